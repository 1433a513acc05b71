"""A small, persistent, Hugging Face–compatible hub server for offline and air-gapped labs.

Run it with ``msta-hub serve --root DIR --token NAME:SECRET`` and point clients at it with
``HF_ENDPOINT=http://127.0.0.1:PORT HF_TOKEN=SECRET``. See docs/hub.md.
"""

from msta.data.hub_server.app import ServerConfig
from msta.data.hub_server.protocol import Limits
from msta.data.hub_server.server import HubServer

__all__ = ["HubServer", "Limits", "ServerConfig"]

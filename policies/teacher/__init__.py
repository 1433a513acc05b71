"""Teachers: the protocol (base.py) and the built-in implementations, registered by name."""

from msta.policies.teacher import config, gait, imported, rma  # noqa: F401  (registration)

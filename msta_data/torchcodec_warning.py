"""One line instead of lerobot's torchcodec traceback.

lerobot picks its default video decoder when a dataset config is built
(``lerobot.utils.import_utils.get_safe_default_video_backend``). Where torchcodec is installed
but FFmpeg's libraries are not, it logs the whole loader exception (~40 lines) before falling
back to pyav. msta datasets hold no video, so for them the message is noise that looks like a
crash. :func:`shorten_torchcodec_warning` adds a logging filter to that one logger which
rewrites that one message to a single line; every other record passes unchanged, and lerobot
itself is not modified. The LeRobot plugins call it on import, so ``lerobot-train`` and
``lerobot-eval`` print the short form.
"""

from __future__ import annotations

import logging

#: The logger lerobot reports the decoder fallback on.
LOGGER = "lerobot.utils.import_utils"
#: The part of lerobot's message that identifies the fallback.
MARK = "'torchcodec' is installed but cannot be loaded"
SHORT = ("torchcodec is installed but cannot be loaded (FFmpeg libraries missing?); lerobot "
         "decodes video with pyav instead (msta datasets hold no video)")


class ShortTorchcodecWarning(logging.Filter):
    """Rewrites lerobot's torchcodec fallback record to :data:`SHORT`; passes the rest."""

    def filter(self, record: logging.LogRecord) -> bool:
        if MARK in record.getMessage():
            record.msg, record.args = SHORT, ()
        return True


def shorten_torchcodec_warning() -> None:
    """Install :class:`ShortTorchcodecWarning` on lerobot's import_utils logger (once)."""
    logger = logging.getLogger(LOGGER)
    if not any(isinstance(f, ShortTorchcodecWarning) for f in logger.filters):
        logger.addFilter(ShortTorchcodecWarning())

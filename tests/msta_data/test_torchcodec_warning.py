"""lerobot's torchcodec fallback warning is one line once msta's filter is installed."""

import logging

from msta.data.torchcodec_warning import (
    LOGGER,
    MARK,
    SHORT,
    ShortTorchcodecWarning,
    shorten_torchcodec_warning,
)


class _Keep(logging.Handler):
    def __init__(self) -> None:
        super().__init__()
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())


def _capture():
    logger = logging.getLogger(LOGGER)
    keep = _Keep()
    logger.addHandler(keep)
    return logger, keep


def test_the_fallback_message_becomes_one_line_and_others_pass():
    shorten_torchcodec_warning()
    shorten_torchcodec_warning()  # idempotent
    logger, keep = _capture()
    try:
        assert sum(isinstance(f, ShortTorchcodecWarning) for f in logger.filters) == 1
        long = ("Could not load libtorchcodec. Likely causes:\n  1. FFmpeg is not properly "
                "installed\n" * 20 + f"\n{MARK} (see the error above). Falling back to 'pyav'.")
        logger.warning(long)
        logger.warning("'torchcodec' is not available in your platform, falling back to %s", "pyav")
        assert keep.lines == [SHORT, "'torchcodec' is not available in your platform, falling back "
                                     "to pyav"]
    finally:
        logger.removeHandler(keep)


def test_lerobots_own_backend_choice_logs_at_most_one_line():
    from lerobot.utils.import_utils import get_safe_default_video_backend

    shorten_torchcodec_warning()
    _, keep = _capture()
    try:
        assert get_safe_default_video_backend() in ("torchcodec", "pyav")
        assert all("\n" not in line for line in keep.lines), keep.lines
    finally:
        logging.getLogger(LOGGER).removeHandler(keep)

"""LeRobot policy plugin: msta's MSTA student as ``lerobot-train --policy.type=msta``.

lerobot imports this package by its distribution name (``lerobot_policy_msta``) at the start
of every lerobot command; importing :mod:`~lerobot_policy_msta.configuration_msta` registers
the ``msta`` policy type and msta-train's learning-rate schedule
(``msta_warmup_cosine``), and :mod:`~lerobot_policy_msta.history` the preprocessor step that
gathers the training windows (``msta_history_processor``, so a saved preprocessor loads
after ``import lerobot_policy_msta``). lerobot finds the rest by its naming convention:
``modeling_msta.MSTAPolicy`` and ``processor_msta.make_msta_pre_post_processors``.
:mod:`~lerobot_policy_msta.convert` converts checkpoints between msta's format and
LeRobot's. See docs/lerobot.md.
"""

from lerobot_policy_msta.configuration_msta import MSTAConfig, WarmupCosineSchedulerConfig
from lerobot_policy_msta.history import HistoryProcessorStep
from msta.data.torchcodec_warning import shorten_torchcodec_warning

__all__ = ["HistoryProcessorStep", "MSTAConfig", "WarmupCosineSchedulerConfig"]

shorten_torchcodec_warning()  # one line, not lerobot's torchcodec traceback

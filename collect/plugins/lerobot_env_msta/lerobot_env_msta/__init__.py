"""LeRobot env plugin: msta's MuJoCo A1 simulator as ``lerobot-eval --env.type=msta_a1``.

lerobot imports this package by its distribution name (``lerobot_env_msta``) at the start of
every lerobot command, which registers the ``msta_a1`` env type (:class:`MstaA1EnvConfig`).
The simulator itself (MuJoCo) loads only when lerobot-eval creates the envs. See
docs/lerobot.md.
"""

from lerobot_env_msta.config import PAPER_TERRAINS, MstaA1EnvConfig
from msta.data.torchcodec_warning import shorten_torchcodec_warning

__all__ = ["PAPER_TERRAINS", "MstaA1EnvConfig"]

shorten_torchcodec_warning()  # one line, not lerobot's torchcodec traceback

"""Transitional: the names other modules still import from here (being rewired in this change)."""

from train.cli import parse_cli  # noqa: F401
from train.config import LoopConfig  # noqa: F401
from train.optim import WarmupCosine, make_optimizer, seed_everything, select_device  # noqa: F401
from train.state import atomic_json  # noqa: F401

"""msta-train's settings (:class:`TrainConfig`), read by its command line
(:mod:`msta.train.offline`), the stage-1 run (:mod:`msta.train.stage1`) and the apps that run
stage 1."""

from __future__ import annotations

from dataclasses import dataclass, field

from msta.data.threads import check_threads
from msta.policies.config import PolicyConfig
from msta.policies.msta import MSTAConfig
from msta.train.config import LoopConfig
from msta.train.push import check_push_to

#: Fields that must match the saved train_config.json when resuming.
RESUME_FIELDS = ("dataset", "more_datasets", "policy", "batch_size", "seed", "val_fraction", "mask_ratio")
#: Values of RESUME_FIELDS in train_config.json files written before the field existed.
RESUME_LEGACY = {"more_datasets": []}


@dataclass
class TrainConfig(LoopConfig):
    """Args:
        dataset: local dataset root, or a hub id ``[datasets/]user/name[@revision]``.
        more_datasets: further datasets trained on together with ``dataset``, of the same
            robot or of others (``[a,b]``): one student for several robots (docs/robots.md).
            Each sample reads the inputs its dataset records; an input another dataset lacks
            is removed from that dataset's samples, which only an MSTA student can do. The
            checkpoint records every dataset's robot.
        policy: the student (``--policy.type=msta``, ``--policy.preset=cpu``,
            ``--policy.<field>=...``).
        output_dir: where checkpoints and metrics go (must be new unless ``resume``).
        resume: continue from ``output_dir/checkpoints/last``.
        val_fraction: share of episodes held out for validation (split by episode).
        device: ``auto`` (CUDA when available, else CPU), ``cpu``, ``cuda``, ``cuda:1``...
        num_threads: torch intra-op threads (0: the cores other work leaves free, msta.data.threads).
        push_to: hub model repo ``user/name``: push ``final/`` with tag ``stage1`` and a
            model card (HF_ENDPOINT / HF_TOKEN); empty = no push. See ``train/push.py``.
        push_private: create that repo as private.
    """

    dataset: str = ""
    more_datasets: tuple[str, ...] = ()
    policy: PolicyConfig = field(default_factory=MSTAConfig)
    output_dir: str = "outputs/train/msta"
    resume: bool = False
    val_fraction: float = 0.1
    device: str = "auto"
    num_threads: int = 0
    push_to: str = ""
    push_private: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        check_push_to(self.push_to)
        if not 0.0 <= self.val_fraction < 1.0:
            raise ValueError(f"val_fraction={self.val_fraction} must be in [0, 1)")
        check_threads(self.num_threads)

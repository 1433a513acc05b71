"""What a student sees at test time (:class:`InputSpec`), apart from the actor that applies
it so that the configs naming one load without torch."""

from __future__ import annotations

from dataclasses import dataclass

from msta.data.robot import NUM_JOINTS
from msta.data.sensors import get
from msta.policies.config import check_fraction


@dataclass
class InputSpec:
    """What the student sees at test time.

    Args:
        history: window length (steps); None = the policy's own (``config.history``).
        drop_sensors: registry sensors removed entirely.
        dead_joints: joint indices (0..11) whose q and qdot channels are removed.
        mask_ratio: fraction of tokens removed at random every step (MSTA's test masks).
        dummy_tokens: random "dummy" tokens appended to every sample (the paper's
            256-token stress test); only token students (``supports_dummy_tokens``) take
            them, others raise ``NotImplementedError`` (msta-eval: not applicable).
        seed: seeds the random token removal and the dummy tokens.
    """

    history: int | None = None
    drop_sensors: tuple[str, ...] = ()
    dead_joints: tuple[int, ...] = ()
    mask_ratio: float = 0.0
    dummy_tokens: int = 0
    seed: int = 0

    def __post_init__(self) -> None:
        self.drop_sensors = tuple(self.drop_sensors)
        self.dead_joints = tuple(int(j) for j in self.dead_joints)
        for s in self.drop_sensors:
            get(s)
        bad = [j for j in self.dead_joints if not 0 <= j < NUM_JOINTS]
        if bad:
            raise ValueError(f"dead joint index {bad[0]} out of range [0, {NUM_JOINTS})")
        if self.history is not None and self.history < 1:
            raise ValueError(f"history={self.history} must be >= 1")
        check_fraction(mask_ratio=self.mask_ratio)
        if self.dummy_tokens < 0:
            raise ValueError(f"dummy_tokens={self.dummy_tokens} must be >= 0")


#: The paper's minimized observation ({cmd, q, g, a_{t-1}}, T = 7).
MINIMIZED_SENSORS = ("command", "joint_pos", "gravity", "last_action")
#: The minimized observation's window (T = 7).
MINIMIZED_HISTORY = 7

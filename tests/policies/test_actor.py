"""StudentActor: per-env history windows, padding, test-time input changes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from msta.policies.actor import StudentActor
from msta.policies.input_spec import InputSpec


class Recorder:
    """A stand-in student that records what it is given (the actor is under test)."""

    class config:
        history = 4

    required_sensors = ("joint_pos", "joint_vel", "command")

    def __init__(self):
        self.calls = []

    def act(self, batch, channels=None, mask_ratio=0.0, generator=None):
        self.calls.append(({k: np.array(v) for k, v in batch.items()}, channels, mask_ratio))
        return torch.zeros(len(batch["pad"]), 12)


def obs_at(t: float, n: int = 3) -> dict[str, np.ndarray]:
    base = np.arange(n, dtype=np.float32)[:, None]
    return {"joint_pos": base + t + np.zeros((n, 12), np.float32),
            "joint_vel": -(base + t) + np.zeros((n, 12), np.float32),
            "command": np.full((n, 3), t, np.float32),
            "gravity": np.zeros((n, 3), np.float32)}


def test_history_padding_and_reset():
    pol = Recorder()
    actor = StudentActor(pol, 3)
    for t in range(3):
        out = actor.act(obs_at(t))
    assert out.shape == (3, 12) and out.dtype == np.float32
    batch, channels, ratio = pol.calls[-1]
    assert batch["joint_pos"].shape == (3, 4, 12)
    # oldest first; the step before the first one repeats the first frame and is padding
    np.testing.assert_array_equal(batch["joint_pos"][0, :, 0], [0, 0, 1, 2])
    np.testing.assert_array_equal(batch["pad"][0], [True, False, False, False])
    assert channels is None and ratio == 0.0
    actor.reset(np.array([1]))
    actor.act(obs_at(10))
    batch = pol.calls[-1][0]
    np.testing.assert_array_equal(batch["pad"][1], [True, True, True, False])
    np.testing.assert_array_equal(batch["joint_pos"][1, :, 0], [11, 11, 11, 11])
    np.testing.assert_array_equal(batch["joint_pos"][0, :, 0], [0, 1, 2, 10])
    assert "gravity" not in batch


def test_dropped_sensor_dead_joints_window_and_mask():
    pol = Recorder()
    spec = InputSpec(history=6, drop_sensors=("command",), dead_joints=(1, 5), mask_ratio=0.5)
    actor = StudentActor(pol, 3, spec)
    actor.act(obs_at(0))
    batch, channels, ratio = pol.calls[-1]
    assert "command" not in batch
    assert batch["joint_pos"].shape == (3, 6, 10) and batch["joint_vel"].shape == (3, 6, 10)
    keep = [j for j in range(12) if j not in (1, 5)]
    assert channels == {"joint_pos": keep, "joint_vel": keep}
    assert ratio == 0.5 and actor.history == 6


def test_bad_specs_error():
    with pytest.raises(KeyError, match="sonar"):
        InputSpec(drop_sensors=("sonar",))
    with pytest.raises(ValueError, match="dead joint index 12"):
        InputSpec(dead_joints=(12,))
    with pytest.raises(ValueError, match="history=0 must be >= 1"):
        InputSpec(history=0)
    with pytest.raises(ValueError, match="nothing left"):
        StudentActor(Recorder(), 2, InputSpec(drop_sensors=("joint_pos", "joint_vel", "command")))


class Echo(Recorder):
    """Acts with its newest joint_pos window row, so each env's action names its env."""

    def act(self, batch, channels=None, mask_ratio=0.0, generator=None):
        super().act(batch, channels, mask_ratio, generator)
        return torch.as_tensor(batch["joint_pos"][:, -1, :]).clone()


def test_mask_split_actor_groups_envs_by_ratio_and_keeps_their_histories():
    from msta.policies.actor import SplitActor, mask_split_actor

    pol = Echo()
    actor = mask_split_actor(pol, 5, InputSpec(), (0.0, 0.5))
    assert isinstance(actor, SplitActor)
    for t in range(3):
        out = actor.act(obs_at(t, n=5))
    # every env gets its own observation back: the groups' outputs land on their envs
    np.testing.assert_array_equal(out[:, 0], np.arange(5) + 2)
    by_ratio = {ratio: batch["joint_pos"][:, :, 0] for batch, _, ratio in pol.calls[-2:]}
    # envs 0, 2, 4 drive at 0 and envs 1, 3 at 0.5, each with its own history
    np.testing.assert_array_equal(by_ratio[0.0], [[0, 0, 1, 2], [2, 2, 3, 4], [4, 4, 5, 6]])
    np.testing.assert_array_equal(by_ratio[0.5], [[1, 1, 2, 3], [3, 3, 4, 5]])
    actor.reset(np.array([3]))  # env 3 = the second env of the 0.5 group
    actor.act(obs_at(10, n=5))
    pads = {ratio: batch["pad"] for batch, _, ratio in pol.calls[-2:]}
    np.testing.assert_array_equal(pads[0.5][:, -2], [False, True])
    assert not pads[0.0][:, -2].any()
    # one ratio (or none): a plain StudentActor at that ratio
    assert isinstance(mask_split_actor(pol, 5, InputSpec(), (0.5, 0.5)), StudentActor)
    assert mask_split_actor(pol, 5, InputSpec(), (0.5,)).spec.mask_ratio == 0.5
    with pytest.raises(ValueError, match="mask_ratio"):
        mask_split_actor(pol, 5, InputSpec(), (0.0, 1.5))
    with pytest.raises(ValueError, match="each once"):
        SplitActor([(np.array([0, 1]), pol), (np.array([1]), pol)])

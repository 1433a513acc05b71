"""Run a student policy in the batched simulator.

``StudentActor`` keeps, for every environment, the last ``history`` steps of the sensors the
student reads, marks the steps before the episode start as padding (filled with the episode's
first frame, exactly like ``msta.data.windows.WindowDataset``), applies the test-time
input changes of the paper's experiments (sensors removed, dead joint encoders, random
token removal, another window length, random dummy tokens appended) and calls the policy on
the whole batch at once; ``act(obs, absent)`` also removes channels per environment (the
channels a fault guard flags).
It has the same ``act(obs)`` / ``reset(ids)`` interface as a teacher.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import torch

from msta.data.robot import NUM_JOINTS
from msta.data.sensors import JOINT_ENCODER_SENSORS, get
from msta.policies.input_spec import InputSpec

#: sensors whose channels are per joint (a dead joint encoder removes q_j and qdot_j)


class StudentActor:
    """A student policy as a batched actor with per-environment history.

    Args:
        policy: a student (``msta.policies.base.Policy``): ``act(batch, channels, mask_ratio,
            generator)`` on raw windows.
        num_envs: environments driven together.
        spec: test-time input changes.
        name: label used in datasets and reports.
    """

    def __init__(self, policy: Any, num_envs: int, spec: InputSpec | None = None,
                 name: str = "student") -> None:
        self.policy = policy
        self.spec = spec = spec or InputSpec()
        self.name = name
        self.num_envs = num_envs
        if spec.dummy_tokens:
            policy.check_dummy_tokens(spec.dummy_tokens)
        self.history = int(spec.history or policy.config.history)
        self.sensors = tuple(s for s in policy.required_sensors if s not in spec.drop_sensors)
        if not self.sensors:
            raise ValueError("every input sensor was dropped; nothing left to act on")
        keep = [j for j in range(NUM_JOINTS) if j not in spec.dead_joints]
        self.channels = {s: keep for s in JOINT_ENCODER_SENSORS
                         if s in self.sensors and spec.dead_joints}
        self.hist = {s: np.zeros((num_envs, self.history,
                                  len(self.channels.get(s, range(get(s).dim)))), dtype=np.float32)
                     for s in self.sensors}
        self.pad = np.ones((num_envs, self.history), dtype=bool)
        self.fresh = np.ones(num_envs, dtype=bool)
        self.offered_checked = False
        self.generator = torch.Generator().manual_seed(spec.seed)

    def reset(self, ids: np.ndarray) -> None:
        """Environments ``ids`` start new episodes: their history is padding."""
        self.pad[ids] = True
        self.fresh[ids] = True

    def _push(self, obs: dict[str, np.ndarray]) -> None:
        fresh = self.fresh
        for s in self.sensors:
            x = obs[s]
            if s in self.channels:
                x = x[:, self.channels[s]]
            h = self.hist[s]
            h[:, :-1] = h[:, 1:]
            h[:, -1] = x
            if fresh.any():
                h[fresh] = x[fresh, None, :]
        self.pad[:, :-1] = self.pad[:, 1:]
        self.pad[:, -1] = False
        self.fresh[:] = False

    def window(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Push this step's observation and return the batch the policy sees."""
        if not self.offered_checked:
            self._drop_unoffered(obs)
        self._push(obs)
        batch = {s: self.hist[s] for s in self.sensors}
        batch["pad"] = self.pad
        return batch

    def _drop_unoffered(self, obs: dict[str, np.ndarray]) -> None:
        """At the first step: inputs the simulated robot does not offer (a student trained on
        several robots, ``msta-train --more_datasets``, reads the sensors of each) are removed
        for good, as a dropped sensor is (``supports_absent`` students: msta's all are)."""
        missing = [s for s in self.sensors if s not in obs]
        if missing:
            self.policy.check_absent()
        if len(missing) == len(self.sensors):
            raise ValueError(f"the simulated robot offers none of the student's inputs "
                             f"{list(self.sensors)}")
        self.sensors = tuple(s for s in self.sensors if s not in missing)
        for s in missing:
            self.hist.pop(s)
        self.offered_checked = True

    def act(self, obs: dict[str, np.ndarray],
            absent: dict[str, np.ndarray] | None = None) -> np.ndarray:
        """(N, 12) actions for this step's observations.

        Args:
            obs: sensor -> (N, dim) readings of this step.
            absent: sensor -> (N, dim) bool over the sensor's full channels: True removes
                that environment's channel from the whole window the student sees now
                (e.g. the channels a fault guard flags; ``policy.act``'s ``absent``). Dropped
                sensors and dead joints stay removed; None or all False: as without it.
        """
        batch = self.window(obs)
        # The generator is passed even without test-time masking: padded steps are removed
        # like masked tokens, and their order must not depend on the global torch RNG.
        kwargs: dict[str, Any] = {"generator": self.generator}
        if self.channels:
            kwargs["channels"] = self.channels
        if self.spec.mask_ratio > 0:
            kwargs["mask_ratio"] = self.spec.mask_ratio
        if self.spec.dummy_tokens:
            kwargs["dummy_tokens"] = self.spec.dummy_tokens
        gone = self._absent(absent)
        if gone is not None:
            kwargs["absent"] = gone
        out = self.policy.act(batch, **kwargs)
        return out.detach().cpu().numpy().astype(np.float32)

    def _absent(self, absent: dict[str, np.ndarray] | None) -> dict[str, torch.Tensor] | None:
        """The removals of the sensors the student reads, as tensors; None when none."""
        if absent is None:
            return None
        out = {}
        for s, mask in absent.items():
            mask = np.asarray(mask)
            if mask.shape != (self.num_envs, get(s).dim) or mask.dtype != np.bool_:
                raise ValueError(f"absent[{s!r}] must be a bool array of shape "
                                 f"{(self.num_envs, get(s).dim)}, got {mask.dtype} {mask.shape}")
            if s in self.sensors and mask.any():  # a dropped sensor is removed already
                out[s] = torch.from_numpy(mask.copy())
        return out or None


class SplitActor:
    """Several actors over disjoint groups of one batch of environments: group ``k`` drives
    the environments ``ids[k]`` (each actor sized to its group). ``act``/``reset`` split the
    batch, so the groups keep their own history and test-time input changes (msta-correct's
    ``rollout_mask_ratios``: some environments driven with tokens removed, some without).

    Args:
        groups: ``(ids, actor)`` pairs; the ids of all groups together are 0..N-1, each once.
    """

    def __init__(self, groups: list[tuple[np.ndarray, Any]]) -> None:
        ids = np.concatenate([np.asarray(i, dtype=np.int64) for i, _ in groups]) if groups else []
        if not len(ids) or sorted(ids.tolist()) != list(range(len(ids))):
            raise ValueError("SplitActor groups must cover environments 0..N-1, each once")
        self.groups = [(np.asarray(i, dtype=np.int64), a) for i, a in groups]
        self.num_envs = len(ids)

    def act(self, obs: dict[str, np.ndarray],
            absent: dict[str, np.ndarray] | None = None) -> np.ndarray:
        """(N, 12) actions: each group's actor on its own environments' observations (and
        removed channels ``absent``: sensor -> (N, dim) bool, as :meth:`StudentActor.act`)."""
        out = np.empty((self.num_envs, NUM_JOINTS), dtype=np.float32)
        for ids, actor in self.groups:
            part = {"absent": {k: v[ids] for k, v in absent.items()}} if absent is not None else {}
            out[ids] = actor.act({k: v[ids] for k, v in obs.items()}, **part)
        return out

    def reset(self, ids: np.ndarray) -> None:
        """Environments ``ids`` (batch indices) start new episodes."""
        for gids, actor in self.groups:
            local = np.nonzero(np.isin(gids, ids))[0]
            if len(local):
                actor.reset(local)


def mask_split_actor(policy: Any, num_envs: int, spec: InputSpec, ratios: tuple[float, ...],
                     name: str = "student") -> StudentActor | SplitActor:
    """``policy`` driving ``num_envs`` environments, environment ``i`` at test-time mask
    ratio ``ratios[i % len(ratios)]`` (the rest of ``spec`` unchanged; each group's token
    removal seeded apart); no ratios: every environment at ``spec.mask_ratio``."""
    ratios = tuple(float(r) for r in ratios)
    if len(set(ratios)) <= 1:
        one = replace(spec, mask_ratio=ratios[0]) if ratios else spec
        return StudentActor(policy, num_envs, one, name=name)
    env_ratio = np.array([ratios[i % len(ratios)] for i in range(num_envs)])
    groups = []
    for k, r in enumerate(sorted(set(ratios))):
        ids = np.nonzero(env_ratio == r)[0]
        if len(ids):
            groups.append((ids, StudentActor(policy, len(ids),
                                             replace(spec, mask_ratio=r, seed=spec.seed + 7919 * k),
                                             name=name)))
    return SplitActor(groups)

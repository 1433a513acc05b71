"""Recording rollouts episode by episode: per-environment buffers (:class:`EpisodeRecorder`),
the actor that drives and labels (:class:`LabelledActor`) and the loop that hands each
finished episode to a writer (:func:`record_rollouts`). msta-collect
(:mod:`msta.collect.record`), its Ray workers (:mod:`msta.collect.ray_record`) and stage 2
record through here.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np
from tqdm import tqdm

from msta.collect.rollout import Step, as_policy, rollout
from msta.collect.sim.env import QuadrupedEnv, StepResult
from msta.data.features import NON_SENSOR_FEATURES
from msta.data.robot import NUM_JOINTS, RobotDescription
from msta.data.sensors import DEFAULT_RECORDED, EXTENSION_SENSORS, SENSORS


def recorded_sensors(robot: RobotDescription, extra: tuple[str, ...] = ()) -> tuple[str, ...]:
    """What a dataset of ``robot`` records: the default recorded sensors it offers
    (``DEFAULT_RECORDED``; on the A1 all of them) plus ``extra``, in registry order.

    Args:
        robot: the simulated robot (its ``sensors``).
        extra: extension sensors to record too (``msta-collect --extra_sensors``).
    Raises:
        ValueError: (one line) an extra that is not an extension sensor, or one the robot
            does not offer (naming the robot and its sensors).
    """
    for name in extra:
        if name not in SENSORS or not SENSORS[name].extension:
            raise ValueError(f"extra_sensors: {name!r} is not an extension sensor (the others "
                             f"are always recorded); extension sensors: "
                             f"{', '.join(EXTENSION_SENSORS)}")
        if name not in robot.sensors:
            raise ValueError(f"extra_sensors: the robot {robot.name!r} does not offer "
                             f"{name!r}; its sensors: {', '.join(robot.sensors)}")
    wanted = {s for s in DEFAULT_RECORDED if s in robot.sensors} | set(extra)
    return tuple(s for s in SENSORS if s in wanted)


class EpisodeRecorder:
    """Per-environment buffers of the running episodes, emitted when an episode ends.

    Args:
        num_envs: environments recorded.
        max_steps: longest episode (the env's time limit in control steps).
        sensors: registry sensors to record.
    """

    def __init__(self, num_envs: int, max_steps: int, sensors: tuple[str, ...]) -> None:
        dims = {SENSORS[s].column: SENSORS[s].dim for s in sensors}
        dims.update({k: int(np.prod(v["shape"])) for k, v in NON_SENSOR_FEATURES.items()})
        self.sensors = sensors
        self.buf = {k: np.zeros((num_envs, max_steps, d),
                                dtype=bool if k == "next.done" else np.float32)
                    for k, d in dims.items()}
        self.ptr = np.zeros(num_envs, dtype=np.int64)
        self.level = np.zeros(num_envs, dtype=np.int64)
        self.type_idx = np.zeros(num_envs, dtype=np.int64)

    def start(self, ids: np.ndarray, type_idx: np.ndarray, level: np.ndarray) -> None:
        self.ptr[ids] = 0
        self.type_idx[ids] = type_idx[ids]
        self.level[ids] = level[ids]

    def add(self, obs: dict[str, np.ndarray], label: np.ndarray, executed: np.ndarray,
            res: StepResult) -> None:
        rows = np.arange(len(self.ptr))
        p = np.minimum(self.ptr, self.buf["action"].shape[1] - 1)
        for s in self.sensors:
            self.buf[SENSORS[s].column][rows, p] = obs[s]
        self.buf["action"][rows, p] = label
        self.buf["executed_action"][rows, p] = executed
        self.buf["next.reward"][rows, p, 0] = res.reward
        self.buf["next.lin_vel_tracking"][rows, p, 0] = res.metrics["lin_vel_tracking"]
        self.buf["next.ang_vel_tracking"][rows, p, 0] = res.metrics["ang_vel_tracking"]
        self.buf["next.done"][rows, p, 0] = res.done
        self.ptr += 1

    def take(self, i: int) -> dict[str, np.ndarray]:
        """Copy out env ``i``'s finished episode."""
        n = int(self.ptr[i])
        return {k: v[i, :n].copy() for k, v in self.buf.items()}


class LabelledActor:
    """``actor`` drives; ``label`` (default: the actor) acts on the same observation right
    after it, once per step, and its action is the recorded ``action`` label
    (``label_action``; the actor's own action is ``actor_action``). With ``beta`` > 0 every
    environment executes the label's action instead with probability ``beta`` per step
    (DAgger mixing, msta-correct). With ``noise`` > 0, Gaussian noise is added to every
    executed action while the label stays clean (DART: the robot visits states off the
    driver's own path, each labelled with the action that returns to it).

    Args:
        actor: the policy that drives (act/reset or a callable).
        label: the labelling policy (a teacher), or None.
        beta: probability that an environment executes the label's action in a step.
        seed: seeds the per-step coin flips and the noise.
        noise: std of the noise on executed actions (action units).
    """

    def __init__(self, actor: Any, label: Any = None, beta: float = 0.0, seed: int = 0,
                 noise: float = 0.0) -> None:
        if noise < 0:
            raise ValueError(f"noise={noise} must be >= 0")
        self._act, self._reset = as_policy(actor)
        self._lab_act, self._lab_reset = (as_policy(label) if label is not None
                                          else (None, lambda ids: None))
        self.beta, self.noise, self.rng = beta, noise, np.random.default_rng(seed)
        self.label_action = np.zeros((0, NUM_JOINTS), dtype=np.float32)
        self.actor_action = self.label_action  # the actor's own answer, before any mixing
        self.label_share = [0, 0]  # label-executed env steps, all env steps

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return self._perturb(self._mix(obs))

    def _mix(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        executed = self.actor_action = np.asarray(self._act(obs), dtype=np.float32)  # (N, 12)
        if self._lab_act is None:
            self.label_action = executed
            return executed
        self.label_action = np.asarray(self._lab_act(obs), dtype=np.float32)
        if self.beta <= 0:  # the usual case: the actor drives, no coin flips needed
            self.label_share[1] += len(executed)
            return executed
        use = self.rng.random(len(executed)) < self.beta          # (N,)
        self.label_share[0] += int(use.sum())
        self.label_share[1] += len(use)
        return np.where(use[:, None], self.label_action, executed)

    def _perturb(self, executed: np.ndarray) -> np.ndarray:
        if self.noise <= 0:
            return executed
        return executed + self.rng.normal(0.0, self.noise, executed.shape).astype(np.float32)

    def reset(self, ids: np.ndarray) -> None:
        self._reset(ids)
        self._lab_reset(ids)


def record_rollouts(env: QuadrupedEnv, actor: Any, episodes: int,
                    write: Callable[[dict[str, np.ndarray], int, int], None],
                    sensors: tuple[str, ...] | None = None, label: Any = None,
                    progress: bool = True, horizon: int | None = None) -> int:
    """Run ``actor`` until ``episodes`` episodes have finished, handing each to ``write``
    (:func:`msta.collect.rollout.rollout` with a recording hook); or, with ``horizon``, for
    exactly ``horizon`` control steps, keeping every frame.

    Args:
        env: the simulator (reset here).
        actor: the policy that drives (act/reset or a callable), or a
            :class:`LabelledActor` (which then also labels; ``label`` must be None).
        episodes: how many finished episodes to emit (ignored with ``horizon``).
        write: called as ``write(frames, type_idx, level)`` per finished episode.
        sensors: registry sensors to record (default: :func:`recorded_sensors` of the
            simulated robot).
        label: the policy whose action is stored as the ``action`` label (default: actor).
        horizon: run this many control steps instead; every episode that ends is emitted,
            and at the end so is every episode still running, cut there (its last
            ``next.done`` false, as after a time limit). The emitted states then follow the
            policy's own state distribution: the first ``episodes`` to finish are the short
            ones (falls), and the steps of the unfinished ones would be simulated for
            nothing.
    Returns:
        environment steps taken.
    """
    sensors = tuple(sensors or recorded_sensors(env.robot))
    if horizon is not None and horizon <= 0:
        raise ValueError(f"horizon={horizon} must be > 0")
    env.reset()
    if episodes <= 0:
        return 0
    policy = actor if isinstance(actor, LabelledActor) and label is None \
        else LabelledActor(actor, label)
    rec = EpisodeRecorder(env.num_envs, env.max_steps, sensors)
    rec.start(np.arange(env.num_envs), env.type_idx, env.level)
    done_count = 0
    bar = EpisodeBar(horizon, episodes, progress, env.num_envs)

    def on_step(step: Step) -> bool:
        nonlocal done_count
        rec.add(step.obs, policy.label_action, step.action, step.res)
        ended = np.flatnonzero(step.res.done)
        for i in ended:
            if horizon or done_count < episodes:
                write(rec.take(i), int(rec.type_idx[i]), int(rec.level[i]))
                done_count += 1
        if len(ended):
            rec.start(ended, env.type_idx, env.level)
        bar.update(step.t, len(ended))
        if horizon:
            return step.t + 1 >= horizon
        return done_count >= episodes

    steps = rollout(env, policy, on_step) * env.num_envs
    if horizon:  # the episodes still running, cut at the horizon
        for i in np.flatnonzero(rec.ptr > 0):
            write(rec.take(i), int(rec.type_idx[i]), int(rec.level[i]))
    bar.bar.close()
    return steps


class EpisodeBar:
    """:func:`record_rollouts`' progress bar: control steps (with ``horizon``) or finished
    episodes, with the simulated frames per second."""

    def __init__(self, horizon: int | None, episodes: int, enabled: bool, num_envs: int) -> None:
        self.bar = (tqdm(total=horizon, disable=not enabled, unit="step", desc="control steps")
                    if horizon else
                    tqdm(total=episodes, disable=not enabled, unit="ep", desc="episodes"))
        self.horizon, self.num_envs, self.t0 = horizon, num_envs, time.time()

    def update(self, t: int, ended: int) -> None:
        """After control step ``t`` (0-based), in which ``ended`` episodes ended."""
        if self.horizon:
            self.bar.update(1)
        elif ended:
            self.bar.update(min(ended, self.bar.total - self.bar.n))
        rate = (t + 1) * self.num_envs / max(time.time() - self.t0, 1e-9)
        self.bar.set_postfix(frames_per_s=f"{rate:,.0f}")

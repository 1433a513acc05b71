"""The one rollout loop: run any policy in the batched simulator.

A policy here is anything with ``act(obs) -> (N, 12)`` and ``reset(ids)`` (every teacher,
and students through their adapters), or a plain callable ``obs -> actions``.

:func:`rollout` is the loop every caller shares: recording (``msta.collect.record``), stage 2
(``msta.train.online`` through recording), the evaluation's trials (``msta.eval.metrics``), the
teacher report, ``msta-sim`` (:func:`run`) and every film (:func:`film`). What differs
between them (recording frames, per-trial bookkeeping, when to stop) is a hook called after
every step with a :class:`Step`; :func:`step_quantities` defines the per-step figures every
summary sums and :func:`fell` which episodes count as not survived.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np
from tqdm import tqdm

from msta.collect.sim.env import REASONS, QuadrupedEnv, StepResult
from msta.collect.sim.render import make_renderer, render_state, tracking_camera


def as_policy(policy: Any) -> tuple[Callable, Callable]:
    """(act, reset) functions of a policy object or a bare callable."""
    if hasattr(policy, "act"):
        return policy.act, getattr(policy, "reset", lambda ids: None)
    if callable(policy):
        return policy, lambda ids: None
    raise TypeError(f"{policy!r} is neither a policy with act() nor a callable")


@dataclass
class Step:
    """One control step of all environments, as :func:`rollout` hands it to its hook.

    Args:
        t: the step's index in this rollout (0-based).
        obs: the observation the action was computed from.
        action: (N, 12) the action executed.
        res: the simulator's result (``res.obs`` is already after auto-resets).
        type_idx: (N,) terrain type of every environment during the step.
        command: (N, 3) command of every environment during the step.
        meas: true base velocities and position at the end of the step, before any
            auto-reset (``QuadrupedEnv.meas_before_reset``).
    """

    t: int
    obs: dict[str, np.ndarray]
    action: np.ndarray
    res: StepResult
    type_idx: np.ndarray
    command: np.ndarray
    meas: dict[str, np.ndarray]


#: What :func:`step_quantities` returns, in order.
STEP_QUANTITIES = ("lin", "ang", "total", "vel_err", "yaw_err")


def step_quantities(step: Step) -> dict[str, np.ndarray]:
    """The per-step figures every summary sums (msta-sim's table, the evaluation's trials,
    the teacher report), each (N,): ``lin`` / ``ang`` the linear- and angular-velocity
    tracking rewards and ``total`` the total reward (the simulator's, already scaled by dt);
    ``vel_err`` |v_xy - cmd_xy| (m/s) and ``yaw_err`` |w_z - cmd_wz| (rad/s) from the true
    base velocities at the end of the step and the command during it."""
    m, cmd, res = step.meas, step.command, step.res
    return {"lin": res.metrics["lin_vel_tracking"], "ang": res.metrics["ang_vel_tracking"],
            "total": res.reward,
            "vel_err": np.linalg.norm(m["base_lin_vel"][:, :2] - cmd[:, :2], axis=1),
            "yaw_err": np.abs(m["base_ang_vel"][:, 2] - cmd[:, 2])}


#: Why an episode ends when it is not survived (indices into ``msta.collect.sim.env.REASONS``).
FALL_REASONS = ("fall", "nan")
_FELL = np.isin(np.arange(len(REASONS)), [REASONS.index(r) for r in FALL_REASONS])


def fell(res: StepResult) -> np.ndarray:
    """(N,) bool: the environments whose episode ended in this step by a fall or a physics
    blow-up (NaN). msta's one survival definition: an episode survives unless it ends so (by
    the time limit, or still running when the figures are taken); every survival figure
    (msta-sim's table, the evaluation's trials, the teacher report, the label check) counts
    the episodes this marks."""
    return res.done & _FELL[res.reason]


#: Called after every step; returning True ends the rollout.
StepHook = Callable[[Step], "bool | None"]


def rollout(env: QuadrupedEnv, policy: Any, on_step: StepHook, max_steps: int | None = None,
            reset_done: bool = True) -> int:
    """Step ``policy`` in ``env`` (already reset) until ``on_step`` returns True or after
    ``max_steps`` steps.

    The policy is reset for every environment first. Each step: ``act`` on the current
    observation, one ``env.step``, then ``on_step(step)``, then (``reset_done``) the policy is
    reset for the environments whose episode ended (the simulator has already started their
    next one).

    Args:
        env: a reset simulator.
        policy: object with act/reset, or a callable obs -> actions.
        on_step: the caller's hook (frames, trial bookkeeping, summaries, a progress bar).
        max_steps: upper bound on control steps (None: until ``on_step`` says stop).
        reset_done: reset the policy of environments whose episode ended (false: only the
            first episode of every environment matters, as in the evaluation's trials).
    Returns:
        the control steps taken (each advances all ``env.num_envs`` environments).
    """
    act, reset = as_policy(policy)
    obs = env.last_obs
    reset(np.arange(env.num_envs))
    t = 0
    while max_steps is None or t < max_steps:
        a = act(obs)
        type_idx, cmd = env.type_idx.copy(), env.commands.command.copy()
        res = env.step(a)
        stop = on_step(Step(t, obs, a, res, type_idx, cmd, env.meas_before_reset))
        if reset_done and res.done.any():
            reset(np.flatnonzero(res.done))
        obs = res.obs
        t += 1
        if stop:
            break
    return t


#: env -> the camera of the next frame (:func:`msta.collect.sim.render.tracking_camera`).
CameraFn = Callable[[QuadrupedEnv], Any]


def film(env: QuadrupedEnv, policy: Any, steps: int, every: int = 5, first: int = 0,
         env_id: int = 0, size: tuple[int, int] = (360, 480), camera: CameraFn | None = None,
         on_step: StepHook | None = None) -> list[np.ndarray]:
    """:func:`rollout` for ``steps`` control steps, filming environment ``env_id``: a frame of
    the state before step ``first`` and then before every ``every``-th step (MuJoCo offscreen,
    ``MUJOCO_GL``; msta-sim's pictures, msta-eval's ``--video``, the teacher report's stairs).

    Args:
        env: a reset simulator.
        policy: object with act/reset, or a callable obs -> actions.
        steps: control steps to run.
        every: control steps between frames.
        first: the step before which the first frame is taken.
        env_id: which environment to film.
        size: (height, width) of the frames.
        camera: the camera of each frame (default: :func:`~msta.collect.sim.render.tracking_camera`).
        on_step: the caller's hook, called after every step before its frame is taken.
    Returns:
        (height, width, 3) uint8 frames.
    """

    renderer = make_renderer(env.model, *size)
    data = mujoco.MjData(env.model)
    fixed = tracking_camera()
    frames: list[np.ndarray] = []

    def shoot(t: int) -> None:  # the state before step t
        if t < steps and t >= first and (t - first) % every == 0:
            cam = camera(env) if camera is not None else fixed
            frames.append(render_state(renderer, env.model, data, env.state[env_id], cam))

    def hook(step: Step) -> None:
        if on_step is not None:
            on_step(step)
        shoot(step.t + 1)

    try:
        shoot(0)
        rollout(env, policy, hook, max_steps=steps)
    finally:
        renderer.close()
    return frames


@dataclass
class TerrainStats:
    """Accumulated per-terrain-type statistics."""

    steps: int = 0
    episodes: int = 0
    fell: int = 0
    lin_tracking: float = 0.0
    ang_tracking: float = 0.0
    total: float = 0.0
    vel_err: float = 0.0
    yaw_err: float = 0.0
    unfinished: int = 0

    def row(self) -> dict[str, float]:
        s = max(self.steps, 1)
        started = max(self.episodes + self.unfinished, 1)
        return {"steps": self.steps, "episodes": self.episodes,
                "survival": 1.0 - self.fell / started,
                "lin_tracking": self.lin_tracking / s, "ang_tracking": self.ang_tracking / s,
                "total": self.total / s, "vel_err": self.vel_err / s, "yaw_err": self.yaw_err / s}


@dataclass
class RolloutSummary:
    types: tuple[str, ...]
    per_type: dict[str, TerrainStats] = field(default_factory=dict)

    def add(self, step: Step) -> None:
        """Sum one step into the rows of the terrain types the environments ran on."""
        q, res = step_quantities(step), step.res
        for t, name in enumerate(self.types):
            sel = step.type_idx == t
            if not sel.any():
                continue
            st = self.per_type.setdefault(name, TerrainStats())
            st.steps += int(sel.sum())
            st.lin_tracking += float(q["lin"][sel].sum())
            st.ang_tracking += float(q["ang"][sel].sum())
            st.total += float(q["total"][sel].sum())
            st.vel_err += float(q["vel_err"][sel].sum())
            st.yaw_err += float(q["yaw_err"][sel].sum())
            done = sel & res.done
            st.episodes += int(done.sum())
            st.fell += int((sel & fell(res)).sum())

    def table(self) -> str:
        """A Markdown table, one row per terrain type."""
        head = ("| terrain | env steps | episodes ended | survival (falls / episodes) | lin track/step | "
                "ang track/step | reward/step | mean |v_xy-cmd| | mean |wz-cmd| |")
        lines = [head, "|" + "---|" * 9]
        for name in self.types:
            if name not in self.per_type:
                continue
            r = self.per_type[name].row()
            lines.append(
                f"| {name} | {r['steps']} | {r['episodes']} | {r['survival']:.2f} | "
                f"{r['lin_tracking']:.4f} | {r['ang_tracking']:.4f} | {r['total']:.4f} | "
                f"{r['vel_err']:.3f} | {r['yaw_err']:.3f} |")
        return "\n".join(lines)


def run(env: QuadrupedEnv, policy: Any, steps: int, progress: bool = True) -> RolloutSummary:
    """:func:`rollout` for ``steps`` control steps, summarized per terrain type (msta-sim).

    Args:
        env: a reset simulator.
        policy: object with act/reset, or a callable obs -> actions.
        steps: control steps (each advances all ``env.num_envs`` environments).
        progress: show a tqdm bar with env steps/s.
    Returns:
        per-terrain-type statistics.
    """
    summary = RolloutSummary(tuple(env.cfg.terrain.types))
    bar = tqdm(total=steps * env.num_envs, disable=not progress, unit="step", unit_scale=True,
               desc="rollout")

    def hook(step: Step) -> None:
        summary.add(step)
        bar.update(env.num_envs)

    rollout(env, policy, hook, max_steps=steps)
    bar.close()
    for t, name in enumerate(summary.types):
        if name in summary.per_type:
            summary.per_type[name].unfinished += int((env.type_idx == t).sum())
    return summary

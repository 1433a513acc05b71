"""Run any policy in the batched simulator and summarize what happened per terrain type.

A policy here is anything with ``act(obs) -> (N, 12)`` and ``reset(ids)`` (every teacher,
and students through their adapters), or a plain callable ``obs -> actions``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from tqdm import tqdm

from collect.sim.env import REASONS, QuadrupedEnv, StepResult


class ZeroPolicy:
    """Holds the default pose (action 0): the teacher-less baseline."""

    name = "zero"
    sensors: tuple[str, ...] = ()

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return np.zeros((len(next(iter(obs.values()))), 12))

    def reset(self, ids: np.ndarray) -> None:
        pass


def as_policy(policy: Any) -> tuple[Callable, Callable]:
    """(act, reset) functions of a policy object or a bare callable."""
    if hasattr(policy, "act"):
        return policy.act, getattr(policy, "reset", lambda ids: None)
    if callable(policy):
        return policy, lambda ids: None
    raise TypeError(f"{policy!r} is neither a policy with act() nor a callable")


@dataclass
class TerrainStats:
    """Accumulated per-terrain-type statistics."""

    steps: int = 0
    episodes: int = 0
    falls: int = 0
    blowups: int = 0
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
                "survival": 1.0 - (self.falls + self.blowups) / started,
                "lin_tracking": self.lin_tracking / s, "ang_tracking": self.ang_tracking / s,
                "total": self.total / s, "vel_err": self.vel_err / s, "yaw_err": self.yaw_err / s}


@dataclass
class RolloutSummary:
    types: tuple[str, ...]
    per_type: dict[str, TerrainStats] = field(default_factory=dict)

    def add(self, env: QuadrupedEnv, res: StepResult, type_idx: np.ndarray,
            cmd: np.ndarray, meas: dict[str, np.ndarray]) -> None:
        vel_err = np.linalg.norm(meas["base_lin_vel"][:, :2] - cmd[:, :2], axis=1)
        yaw_err = np.abs(meas["base_ang_vel"][:, 2] - cmd[:, 2])
        for t, name in enumerate(self.types):
            sel = type_idx == t
            if not sel.any():
                continue
            st = self.per_type.setdefault(name, TerrainStats())
            st.steps += int(sel.sum())
            st.lin_tracking += float(res.metrics["lin_vel_tracking"][sel].sum())
            st.ang_tracking += float(res.metrics["ang_vel_tracking"][sel].sum())
            st.total += float(res.reward[sel].sum())
            st.vel_err += float(vel_err[sel].sum())
            st.yaw_err += float(yaw_err[sel].sum())
            done = sel & res.done
            st.episodes += int(done.sum())
            st.falls += int((done & (res.reason == REASONS.index("fall"))).sum())
            st.blowups += int((done & (res.reason == REASONS.index("nan"))).sum())

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


def run(env: QuadrupedEnv, policy: Any, steps: int, progress: bool = True,
        on_step: Callable[[dict, np.ndarray, StepResult], None] | None = None,
        ) -> RolloutSummary:
    """Step ``policy`` in ``env`` (already reset) for ``steps`` control steps.

    Args:
        env: a reset simulator.
        policy: object with act/reset, or a callable obs -> actions.
        steps: control steps (each advances all ``env.num_envs`` environments).
        progress: show a tqdm bar with env steps/s.
        on_step: called with (obs before the step, actions, result) after every step.
    Returns:
        per-terrain-type statistics.
    """
    act, reset = as_policy(policy)
    summary = RolloutSummary(tuple(env.cfg.terrain.types))
    obs = env.last_obs
    reset(np.arange(env.num_envs))
    bar = tqdm(total=steps * env.num_envs, disable=not progress, unit="step", unit_scale=True,
               desc="rollout")
    for _ in range(steps):
        a = act(obs)
        type_idx, cmd = env.type_idx.copy(), env.commands.command.copy()
        res = env.step(a)
        summary.add(env, res, type_idx, cmd, env.meas_before_reset)
        if on_step is not None:
            on_step(obs, a, res)
        if res.done.any():
            reset(np.flatnonzero(res.done))
        obs = res.obs
        bar.update(env.num_envs)
    bar.close()
    for t, name in enumerate(summary.types):
        if name in summary.per_type:
            summary.per_type[name].unfinished += int((env.type_idx == t).sum())
    return summary

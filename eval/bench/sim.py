"""Benchmark: batched env control steps/s vs raw ``mujoco.rollout`` of the same model.

Both run in the same process, interleaved in rounds, on the same states, thread count
and environment count; the ratio is the median of per-round ratios, so it is robust to a
busy machine (absolute figures are medians over rounds and follow the machine's speed).

    python -m msta.eval.bench.sim [--num_envs 1024] [--steps 50] [--rounds 5] [--collision fast]
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import mujoco
import numpy as np
from mujoco import rollout

from msta.collect.sim import robot
from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig
from msta.data.cli import parse_config
from msta.data.robot import DEFAULT_POSE, NUM_JOINTS


def _raw_rate(env: QuadrupedEnv, actions: np.ndarray) -> float:
    """Control steps/s of bare rollout calls chaining the final state, no observations,
    applying the same action sequence as the env measurement."""
    runner = rollout.Rollout(nthread=len(env._datas))
    state = env.state.copy()
    d = env.cfg.control.decimation
    control = np.zeros_like(env._control)
    out_s = np.zeros((env.num_envs, d, env.layout.size))
    out_sens = np.zeros((env.num_envs, d, env.model.nsensordata))
    scale = env.cfg.control.action_scale
    t = time.perf_counter()
    for a in actions:
        control[:] = (DEFAULT_POSE + scale * a)[:, None, :]
        runner.rollout(env._models, env._datas, state, control,
                       control_spec=mujoco.mjtState.mjSTATE_CTRL.value, skip_checks=True,
                       nstep=d, state=out_s, sensordata=out_sens)
        state[:] = out_s[:, -1]
    return len(actions) * env.num_envs / (time.perf_counter() - t)


def _env_rate(env: QuadrupedEnv, actions: np.ndarray) -> float:
    t = time.perf_counter()
    for a in actions:
        env.step(a)
    return len(actions) * env.num_envs / (time.perf_counter() - t)


@dataclass
class BenchSimConfig:
    """Args:
        num_envs: robots simulated in parallel.
        steps: control steps per measurement.
        rounds: measurements (the median counts).
        nthread: MuJoCo rollout threads (EnvConfig.nthread).
        collision: robot collision set (EnvConfig.collision): fast or full.
    """

    num_envs: int = 1024
    steps: int = 50
    rounds: int = 5
    nthread: int = 2
    collision: str = "fast"

    def __post_init__(self) -> None:
        robot.check_collision_set(self.collision)
        if min(self.num_envs, self.steps, self.rounds, self.nthread) < 1:
            raise ValueError("num_envs, steps, rounds and nthread must be >= 1")


def main(argv: list[str] | None = None) -> None:
    args = parse_config(BenchSimConfig, argv, prog="python -m msta.eval.bench.sim")
    env = QuadrupedEnv(EnvConfig(num_envs=args.num_envs, nthread=args.nthread, seed=0,
                               collision=args.collision))
    env.reset()
    rng = np.random.default_rng(0)
    _env_rate(env, np.zeros((10, env.num_envs, NUM_JOINTS)))  # warm-up: let robots land
    env_rates, raw_rates = [], []
    for r in range(args.rounds):
        # a trotting-like excitation: the same random joint targets for both measurements
        actions = rng.normal(0, 0.3, (args.steps, env.num_envs, NUM_JOINTS))
        raw_rates.append(_raw_rate(env, actions))
        env_rates.append(_env_rate(env, actions))
        print(f"round {r}: env {env_rates[-1]:,.0f} steps/s | raw rollout {raw_rates[-1]:,.0f} "
              f"steps/s")
    env_r, raw_r = float(np.median(env_rates)), float(np.median(raw_rates))
    # Each round's env and raw figures are measured back to back, so their ratio cancels
    # the machine's speed drift; the median over rounds is the reported ratio.
    ratio = float(np.median(np.asarray(env_rates) / np.asarray(raw_rates)))
    print(f"num_envs={args.num_envs} nthread={args.nthread} collision={args.collision} "
          f"terrain types={env.cfg.terrain.types}")
    print(f"batched env (all sensors + privileged, rewards, resets): {env_r:,.0f} control steps/s")
    print(f"raw mujoco.rollout, same model and states:              {raw_r:,.0f} control steps/s")
    print(f"env/raw ratio: {ratio:.2f} (median of per-round ratios)")


if __name__ == "__main__":
    main()

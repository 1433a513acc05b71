"""A Gymnasium ``VectorEnv`` view of the batched simulator, so other libraries can drive it.

Observations are a ``Dict`` space keyed by registry sensor name. The simulator resets
finished environments inside ``step`` (Gymnasium's SAME_STEP autoreset mode): the returned
observation of a finished env is its next episode's first one, and the last observation of
the finished episode is in ``infos["final_obs"]`` (masked by ``infos["_final_obs"]``).
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from collect.sim.env import REASONS, EnvConfig, QuadrupedEnv
from msta_data.robot import NUM_JOINTS
from msta_data.sensors import SENSORS, get


class MstaVectorEnv(VectorEnv):
    """Gymnasium vector env over ``QuadrupedEnv``.

    Args:
        cfg: simulator config (``cfg.num_envs`` environments).
        sensors: registry sensors to expose (default: all, privileged included).
    """

    metadata: ClassVar[dict] = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(self, cfg: EnvConfig | None = None, sensors: tuple[str, ...] | None = None):
        self.sim = QuadrupedEnv(cfg)
        self.num_envs = self.sim.num_envs
        self.sensors = tuple(sensors) if sensors else tuple(SENSORS)
        for s in self.sensors:
            get(s)
        self.single_observation_space = gym.spaces.Dict({
            s: gym.spaces.Box(-np.inf, np.inf, (get(s).dim,), np.float32) for s in self.sensors})
        self.single_action_space = gym.spaces.Box(-100.0, 100.0, (NUM_JOINTS,), np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)

    def _select(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {s: obs[s] for s in self.sensors}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset all envs. ``seed`` reseeds the simulator's generator; ``options`` may hold
        ``type_idx`` and ``level`` arrays to pin terrain tiles."""
        if seed is not None:
            self.sim.rng = np.random.default_rng(seed)
        options = options or {}
        obs = self.sim.reset(options.get("type_idx"), options.get("level"))
        return self._select(obs), {}

    def step(self, actions: np.ndarray):
        res = self.sim.step(actions)
        done = res.done
        infos: dict[str, Any] = {
            "lin_vel_tracking": res.metrics["lin_vel_tracking"],
            "ang_vel_tracking": res.metrics["ang_vel_tracking"],
            "reason": np.array([REASONS[i] for i in res.reason]),
        }
        if done.any():
            final = {}
            for k in self.sensors:
                final[k] = np.zeros((self.num_envs, get(k).dim), dtype=np.float32)
                final[k][self.sim.final_ids] = self.sim.final_obs[k]
            infos["final_obs"] = final
            infos["_final_obs"] = done.copy()
        return self._select(res.obs), res.reward.astype(np.float32), res.terminated, \
            res.truncated, infos

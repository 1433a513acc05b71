"""The vector env lerobot-eval steps: msta's batched simulator with LeRobot's observation keys.

:class:`A1VectorEnv` wraps :class:`msta.collect.sim.gym_env.MstaVectorEnv` (one simulator, all
robots of a batch, NEXT_STEP autoreset) and changes only what LeRobot reads:

- observations ``{"agent_pos": (N, 49), "environment_state": (N, 3)}`` (the A1's; on a robot
  that offers fewer student sensors, ``agent_pos`` holds those: the Go1's 45), which lerobot's
  ``preprocess_observation`` turns into ``observation.state`` / ``observation.environment_state``;
  built by :func:`msta.data.derived.derive`, the function that writes those columns into
  msta datasets, so a policy sees here what it was trained on;
- ``infos["is_success"]``: True for the robots whose episode ends this step at the time limit
  (still standing), which lerobot-eval counts as ``pc_success``;
- ``call`` / ``get_attr`` (lerobot-eval asks for ``_max_episode_steps``, ``task``,
  ``task_description`` and ``render`` through them), with ``reset(seed=[...])`` taking
  lerobot-eval's per-episode seeds and ``reset(options=...)`` ignoring lerobot's markers.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from msta.collect.sim.env_config import EnvConfig as SimConfig
from msta.collect.sim.gym_env import MstaVectorEnv, view_sensors
from msta.data import derived
from msta.data.sensors import get

#: Env observation key -> the msta dataset column it equals.
OBS_COLUMNS: dict[str, str] = {"agent_pos": derived.STATE_COLUMN,
                               "environment_state": derived.ENV_STATE_COLUMN}
#: Side of the gray frames ``render()`` returns when filming is off.
BLANK_SIZE = 16
#: What lerobot-eval does with ``--env.video=false`` (said once, when it first asks for a frame).
VIDEO_OFF_WARNING = (
    "msta_a1 --env.video=false: nothing is rendered, but lerobot-eval films every evaluation "
    "that does not record, so it writes up to 10 MP4s per terrain of blank 16x16 frames and "
    "lists them in eval_info.json; add --eval.recording=true for no video files (it then "
    "records the rollouts as LeRobot datasets under <output_dir>/recordings)")
logger = logging.getLogger(__name__)


class A1VectorEnv(VectorEnv):
    """``num_envs`` robots on one terrain type, as lerobot-eval expects a vector env.

    Args:
        cfg: the simulator config (``cfg.num_envs`` robots of ``cfg.robot``; its terrain has
            one type).
        task: the task label (the terrain type) returned by ``call("task")``.
        levels: terrain levels; episode k of a reset runs on ``levels[seed_k % len(levels)]``
            (random among them when the reset has no seed).
        video: render the robots in ``render()``; False returns gray frames.
        width, height: frame size.
        video_robots: robots rendered (the first ones); the others get gray frames (what
            lerobot-eval drops).
        shadows: frames with shadows.
    """

    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 50,
                                "autoreset_mode": AutoresetMode.NEXT_STEP}
    _warned_video_off: ClassVar[bool] = False  # VIDEO_OFF_WARNING is said once a process

    def __init__(self, cfg: SimConfig, task: str, levels: Sequence[int], video: bool = True,
                 width: int = 320, height: int = 240, video_robots: int = 10,
                 shadows: bool = False) -> None:
        if len(cfg.terrain.types) != 1:
            raise ValueError(f"A1VectorEnv runs one terrain type, got {cfg.terrain.types}")
        self.levels = np.asarray(levels, dtype=np.int64)
        self.video, self.video_robots = video, int(video_robots)
        # the student sensors the robot offers (the A1: STUDENT_SENSORS), as its datasets hold
        self.sensors = view_sensors(cfg.robot_description, None)
        self.sim_env = MstaVectorEnv(cfg, sensors=self.sensors, actions="simulator",
                                     render_mode="rgb_array" if video else None,
                                     width=width, height=height)
        self.sim_env.shadows = shadows
        self.num_envs = self.sim_env.num_envs
        self.task = task
        self.task_description = (f"walk on {task} terrain (levels {list(self.levels)}) "
                                 "following the velocity command")
        self._max_episode_steps = cfg.max_episode_steps
        self.render_mode = "rgb_array"
        self.metadata = {**type(self).metadata, "render_fps": int(round(1.0 / cfg.dt))}
        columns = [get(s).column for s in self.sensors]
        self._columns = (*columns, *derived.COLUMNS)
        sensor_space = self.sim_env.single_observation_space  # finite ranges (spaces.py)
        self.single_observation_space = gym.spaces.Dict({k: gym.spaces.Box(
            np.concatenate([sensor_space[s].low for s in self._sources(k)]),
            np.concatenate([sensor_space[s].high for s in self._sources(k)]), dtype=np.float32)
            for k in OBS_COLUMNS})
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.single_action_space = self.sim_env.single_action_space
        self.action_space = self.sim_env.action_space

    def _sources(self, key: str) -> list[str]:
        """Registry sensors concatenated into env observation ``key``."""
        by_column = {get(s).column: s for s in self.sensors}
        srcs = derived.sources(by_column)[OBS_COLUMNS[key]]
        return [by_column[c] for c in srcs]

    def _observe(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Simulator observations (sensor name -> (N, dim)) -> LeRobot's keys."""
        cols = derived.derive({get(s).column: obs[s] for s in self.sensors}, self._columns)
        return {k: cols[c].astype(np.float32, copy=False) for k, c in OBS_COLUMNS.items()}

    def reset(self, *, seed: int | Sequence[int] | None = None,
              options: dict[str, Any] | None = None):
        """Start an episode on every robot.

        Args:
            seed: per-robot seeds (lerobot-eval passes one per episode), or an int s meaning
                s, s + 1, ...; the first seeds the batch's random stream, each picks its
                robot's level. None: no reseeding, random levels.
            options: ignored (lerobot passes its own rollout markers).
        """
        n = self.num_envs
        if seed is None:
            seeds, first = None, None
        else:
            seeds = (np.arange(n) + int(seed) if np.isscalar(seed)
                     else np.asarray(list(seed), dtype=np.int64))
            if seeds.shape != (n,):
                raise ValueError(f"reset got {seeds.size} seeds for {n} envs")
            first = int(seeds[0])
        if seeds is None:
            level = self.sim_env.np_random.choice(self.levels, size=n)
        else:
            level = self.levels[seeds % len(self.levels)]
        obs, _ = self.sim_env.reset(seed=first, options={
            "type_idx": np.zeros(n, dtype=np.int64), "level": level})
        return self._observe(obs), {}

    def step(self, actions: np.ndarray):
        """One control step of every robot: (obs, reward, terminated, truncated, infos);
        ``infos["is_success"]`` is True where an episode reached its time limit now."""
        obs, reward, term, trunc, infos = self.sim_env.step(np.asarray(actions))
        infos["is_success"] = trunc & ~term
        return self._observe(obs), reward, term, trunc, infos

    def render(self) -> tuple[np.ndarray, ...]:
        """One (height, width, 3) uint8 frame per robot (gray squares when ``video`` is off,
        with ``VIDEO_OFF_WARNING`` the first time)."""
        if not self.video:
            if not A1VectorEnv._warned_video_off:
                A1VectorEnv._warned_video_off = True
                logger.warning(VIDEO_OFF_WARNING)
            return tuple(np.full((BLANK_SIZE, BLANK_SIZE, 3), 128, np.uint8)
                         for _ in range(self.num_envs))
        return self.sim_env.render_first(self.video_robots)

    def call(self, name: str, *args: Any, **kwargs: Any) -> tuple[Any, ...]:
        """An attribute of the env for every robot (called when it is a method): lerobot-eval's
        ``env.call("render")``, ``env.call("_max_episode_steps")``, ``env.call("task")``."""
        if name == "render":
            return self.render()
        value = getattr(self, name)  # AttributeError for anything else, as lerobot expects
        if callable(value):
            value = value(*args, **kwargs)
        return (value,) * self.num_envs

    def get_attr(self, name: str) -> tuple[Any, ...]:
        """An attribute of the env, once per robot."""
        return (getattr(self, name),) * self.num_envs

    def close_extras(self, **kwargs: Any) -> None:
        self.sim_env.close()

"""msta's batched simulator behind rsl_rl's ``VecEnv`` interface.

Observations are a TensorDict with two groups, scaled exactly as the RMA teacher scales
its inputs (``msta.policies.teacher.rma.RMAConfig``): ``privileged`` (e_t: base velocity,
orientation, height scan, dynamics) and ``proprio`` (o_t: the student's 49 scalars).
rsl_rl's runners pick groups per model through ``obs_groups`` (actor and critic both read
both here). ``step`` returns rsl_rl's (obs, rewards, dones, extras) with
``extras["time_outs"]`` (time-limit ends, bootstrapped by PPO) and ``extras["log"]``
(terrain level, episode figures); environments reset inside ``step`` (the returned
observation of a finished env is its next episode's first one), which is rsl_rl's
convention. ``episode_length_buf`` is the simulator's episode step counter, so
``init_at_random_ep_len`` spreads the time-outs as in legged_gym.
"""

from __future__ import annotations

from dataclasses import asdict

import numpy as np
import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from msta.collect.rollout import fell
from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig
from msta.data.robot import NUM_JOINTS
from msta.policies.teacher.imported import InputScaler
from msta.policies.teacher.rma import RMAConfig

#: observation group names (rsl_rl ``obs_groups`` values)
PRIVILEGED, PROPRIO = "privileged", "proprio"


class RslVecEnv(VecEnv):
    """rsl_rl ``VecEnv`` over ``QuadrupedEnv``.

    Args:
        env_cfg: the simulator's configuration (``num_envs`` robots).
        rma: the teacher whose input scaling the observation groups follow (default:
            ``RMAConfig.for_robot`` of the simulated robot, its default pose).
        device: torch device of the returned tensors.
    """

    def __init__(self, env_cfg: EnvConfig, rma: RMAConfig | None = None,
                 device: str | torch.device = "cpu") -> None:
        self.sim = QuadrupedEnv(env_cfg)
        self.rma = rma = rma or RMAConfig.for_robot(env_cfg.robot_description)
        self.priv_in, self.proprio_in = InputScaler(rma.privileged), InputScaler(rma.proprio)
        self.num_envs = env_cfg.num_envs
        self.num_actions = NUM_JOINTS
        self.max_episode_length = self.sim.max_steps
        self.device = torch.device(device)
        self.cfg = asdict(env_cfg)
        self.raw_obs = self.sim.reset()
        self.stats = self._zero_stats()

    @staticmethod
    def _zero_stats() -> dict[str, float]:
        return {"env_steps": 0, "episodes": 0, "falls": 0, "timeouts": 0, "distance": 0.0,
                "level": 0.0, "lin_vel_tracking": 0.0}

    def take_stats(self) -> dict[str, float]:
        """Counters since the last call (env steps, episodes ended, falls: the episodes that
        :func:`msta.collect.rollout.fell` marks, physics blow-ups included; time-outs, summed
        distance and level at the episode ends, summed linear tracking reward), then zeroed."""
        out, self.stats = self.stats, self._zero_stats()
        return out

    def curve_row(self, st: dict[str, float], **head) -> dict:
        """A ``curve.json`` row from one chunk's :meth:`take_stats`: ``head`` (iteration,
        env steps so far, ...), then episodes, falls per 1000 robot steps and
        ``full_episode_at_fall_rate``: the chance a robot lasts a whole episode if it falls at
        that constant rate per step (a model, not a count: the share of ended episodes that
        timed out depends on where the episodes' clocks stand; msta's survival is a count,
        :func:`msta.eval.metrics.survival`), the mean level and distance at the episode ends
        and the linear tracking reward per robot step."""
        eps, robot_steps = max(st["episodes"], 1), max(st["env_steps"], 1)
        hazard = st["falls"] / robot_steps
        return {**head, "episodes": st["episodes"], "falls": st["falls"],
                "falls_per_1000_steps": 1000.0 * hazard,
                "full_episode_at_fall_rate": float(np.exp(-hazard * self.max_episode_length)),
                "mean_level_at_end": st["level"] / eps, "distance_m": st["distance"] / eps,
                "lin_vel_tracking_per_step": st["lin_vel_tracking"] / robot_steps}

    # rsl_rl reads and writes this buffer (init_at_random_ep_len): it is the simulator's
    # own step counter, seen as a tensor.
    @property
    def episode_length_buf(self) -> torch.Tensor:
        return torch.from_numpy(self.sim.episode_step)

    @episode_length_buf.setter
    def episode_length_buf(self, value: torch.Tensor) -> None:
        steps = np.asarray(value.cpu().numpy(), dtype=np.int64)
        # leave at least one step so no env times out before it has acted
        self.sim.episode_step[:] = np.clip(steps, 0, self.max_episode_length - 1)

    def groups(self, obs: dict[str, np.ndarray]) -> TensorDict:
        """Registry-keyed numpy observations -> the scaled TensorDict groups."""
        t = {PRIVILEGED: torch.from_numpy(self.priv_in(obs)),
             PROPRIO: torch.from_numpy(self.proprio_in(obs))}
        return TensorDict({k: v.to(self.device) for k, v in t.items()},
                          batch_size=[self.num_envs], device=self.device)

    def get_observations(self) -> TensorDict:
        return self.groups(self.raw_obs)

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        a = actions.detach().to("cpu", torch.float64).numpy()
        res = self.sim.step(a)
        self.raw_obs = res.obs
        done = res.done
        st, ids = self.stats, np.flatnonzero(done)
        st["env_steps"] += self.num_envs
        st["lin_vel_tracking"] += float(res.metrics["lin_vel_tracking"].sum())
        if len(ids):
            st["episodes"] += len(ids)
            st["falls"] += int(fell(res)[ids].sum())
            st["timeouts"] += int(res.truncated[ids].sum())
            st["distance"] += float(res.final["distance"][ids].sum())
            st["level"] += float(res.final["level"][ids].sum())
        extras: dict = {"time_outs": torch.from_numpy(res.truncated).to(self.device),
                        "log": self._log(res, done)}
        rew = torch.from_numpy(res.reward.astype(np.float32)).to(self.device)
        return (self.observe(res), rew, torch.from_numpy(done).to(self.device), extras)

    def observe(self, res) -> TensorDict:
        """The groups returned by ``step`` for the step result ``res`` (a subclass that keeps
        per-environment state, e.g. a history window, updates it here, once per step)."""
        return self.groups(res.obs)

    def _log(self, res, done: np.ndarray) -> dict[str, float]:
        # a "/" in the key: rsl_rl uses it as the TensorBoard tag (no "Episode/" prefix)
        log = {"Env/terrain_level": float(self.sim.level.mean()),
               "Env/lin_vel_tracking": float(res.metrics["lin_vel_tracking"].mean())}
        if done.any():
            ids = np.flatnonzero(done)
            log["Episode/fall_rate"] = float(fell(res)[ids].mean())
            log["Episode/distance_m"] = float(res.final["distance"][ids].mean())
        return log

"""Batched legged-robot locomotion environment on MuJoCo (numpy in, numpy out).

N environments share one scene (the robot ``cfg.robot`` names + terrain heightfield; the
A1 by default) and are stepped together by
``mujoco.rollout`` on a persistent thread pool: every control step is ``decimation``
physics steps with a constant position target. Observations are named by the sensor
registry (``msta_data/sensors.py``) and are the sensors the robot's description lists;
environments reset automatically on a fall, a physics blow-up or the time limit.

Random draws (spawns, domain-randomization variants, commands, latency, pushes, observation
noise) come from one generator seeded by ``cfg.seed``, or, after
``reset(streams=keys)``, from one generator per environment keyed by
``(cfg.seed, keys[i])``: then what happens in one environment (a fall, an early reset)
never shifts the random numbers of another, and an environment's episodes are the same
whatever batch it runs in (the evaluation's trials, ``eval/metrics.py``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import mujoco
import numpy as np
from mujoco import rollout

from msta.collect.sim import robot
from msta.collect.sim.commands import CommandSampler
from msta.collect.sim.env_config import ControlConfig, EnvConfig, NoiseConfig
from msta.collect.sim.randomization import build_pool
from msta.collect.sim.rewards import RewardInputs, compute_rewards, soft_limits
from msta.collect.sim.terrain import Terrain, sample_initial, update_levels
from msta.data.math3d import quat_to_mat, world_to_body, yaw_of, yaw_quat
from msta.data.sensors import HEIGHT_SCAN_X, HEIGHT_SCAN_Y, SENSORS

PROPRIO = ("joint_pos", "joint_vel", "ang_vel", "gravity", "foot_contact")
#: Episode end reasons reported in ``StepResult.reason``.
REASONS = ("running", "fall", "timeout", "nan")
#: Salt of the sourced sensors' noise streams (``QuadrupedEnv.seed_sources``).
SOURCE_SALT = 0x5E45
#: Salt of the per-environment generators of ``QuadrupedEnv.reset(streams=...)``.
STREAM_SALT = 0x7E57
#: The configuration classes live in env_config.py; importing them from here keeps working.
__all__ = ["PROPRIO", "REASONS", "STREAM_SALT", "ControlConfig",
           "EnvConfig", "NoiseConfig", "QuadrupedEnv", "StepResult"]


@dataclass
class StepResult:
    """One control step of all environments.

    ``obs`` is the observation after the step; for environments that ended this step it is
    already the first observation of their next episode (auto-reset), and their final
    values are in ``final`` (reason, terrain, level, length, return, distance).
    """

    obs: dict[str, np.ndarray]
    reward: np.ndarray                 # (N,) total reward
    metrics: dict[str, np.ndarray]     # lin_vel_tracking, ang_vel_tracking, total, terms
    terminated: np.ndarray             # (N,) bool: fall or physics blow-up
    truncated: np.ndarray              # (N,) bool: time limit
    reason: np.ndarray                 # (N,) int index into REASONS
    final: dict[str, np.ndarray]       # per-env episode summary, valid where done

    @property
    def done(self) -> np.ndarray:
        return self.terminated | self.truncated


class QuadrupedEnv:
    """Batched environments. See the module docstring.

    Args:
        cfg: the environment configuration; ``self.cfg`` is its :meth:`EnvConfig.resolved`
            copy (every ``control`` field a number) and ``self.robot`` the robot's description.
    """

    def __init__(self, cfg: EnvConfig | None = None) -> None:
        self.cfg = cfg = (cfg or EnvConfig()).resolved()
        self.robot = cfg.robot_description
        self._default_pose = np.array(self.robot.default_pose, dtype=np.float64)
        self.num_envs = n = cfg.num_envs
        self.rng = np.random.default_rng(cfg.seed)
        self.seed_sources(cfg.seed)
        self.terrain = Terrain(cfg.terrain, seed=cfg.seed)
        self.model = robot.build_model(self.terrain.hfield_spec(), timestep=cfg.control.sim_dt,
                                      collision=cfg.collision, robot=self.robot)
        self.layout = robot.state_layout(self.model)
        #: Where the accelerometer (``base_accel``) sits in ``sensordata``; None: no such sensor.
        self._accel = robot.imu_sensor(self.model, self.robot, "accel")
        self._offered = frozenset(self.robot.sensors)
        self.pool, self.pool_params = build_pool(
            self.model, cfg.randomization, cfg.control.kp, cfg.control.kd, self.rng)
        nthread = cfg.nthread or os.cpu_count() or 1
        self._runner = rollout.Rollout(nthread=nthread)
        self._datas = [mujoco.MjData(self.model) for _ in range(nthread)]
        self._template = robot.default_state(self.model, self.robot)
        #: (legs + 1, 2) points a reset probes the ground at (robot.spawn_footprint)
        self._footprint = robot.spawn_footprint(self.robot)
        self.soft_limits = soft_limits(robot.joint_limits(self.model),
                                       cfg.rewards.soft_dof_pos_limit)
        self.dt = cfg.dt
        self.max_steps = cfg.max_episode_steps
        self.commands = CommandSampler(cfg.commands, n)
        scan = np.stack(np.meshgrid(HEIGHT_SCAN_X, HEIGHT_SCAN_Y, indexing="ij"), -1)
        self._scan_points = scan.reshape(-1, 2)                       # (187, 2), x-major
        self._noise = {k: (SENSORS[k].noise * cfg.noise.scale if cfg.noise.enabled else 0.0)
                       for k in PROPRIO}
        self._noise_width = np.concatenate([np.full(SENSORS[k].dim, self._noise[k])
                                            for k in PROPRIO])
        #: Per-environment generators (``reset(streams=...)``); None: the shared ``rng``.
        self.streams: list[np.random.Generator] | None = None
        self._source_streams: list[np.random.Generator] | None = None
        self._lat = cfg.randomization.max_latency_steps if cfg.randomization.enabled else 0
        self._alloc(n)
        self.type_idx, self.level = sample_initial(
            n, self.rng, cfg.terrain, list(cfg.type_weights) or None)
        self.resets_by_reason = np.zeros(len(REASONS), dtype=np.int64)
        self._needs_reset = True

    # ------------------------------------------------------------------ allocation
    def _alloc(self, n: int) -> None:
        d = self.cfg.control.decimation
        self.state = np.zeros((n, self.layout.size))
        self._out_state = np.zeros((n, d, self.layout.size))
        self._out_sens = np.zeros((n, d, self.model.nsensordata))
        self._control = np.zeros((n, d, self.model.nu))
        self.variant = np.zeros(n, dtype=np.int64)
        self._models = [self.pool[0]] * n
        nj = self.robot.num_joints
        self.action = np.zeros((n, nj))
        self.last_action = np.zeros((n, nj))
        self.last_joint_vel = np.zeros((n, nj))
        self.air_time = np.zeros((n, 4))
        self.last_contact = np.zeros((n, 4), dtype=bool)
        self.episode_step = np.zeros(n, dtype=np.int64)
        self.episode_return = np.zeros(n)
        self.spawn_xy = np.zeros((n, 2))
        self.latency = np.zeros(n, dtype=np.int64)
        self.push_step = np.zeros(n, dtype=np.int64)
        self._hist = np.zeros((n, self._lat + 1, sum(SENSORS[k].dim for k in PROPRIO)),
                              dtype=np.float32)
        self.meas: dict[str, np.ndarray] = {}
        self.last_obs: dict[str, np.ndarray] = {}
        self.final_obs: dict[str, np.ndarray] = {}
        self.final_ids = np.zeros(0, dtype=np.int64)
        self._hist_fresh = np.zeros(0, dtype=np.int64)

    # ------------------------------------------------------------------ public API
    def reset(self, type_idx: np.ndarray | None = None, level: np.ndarray | None = None,
              streams: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Reset every environment; optionally pin each one's terrain type and level.

        Args:
            type_idx: (N,) indices into ``cfg.terrain.types`` (kept for later episodes).
            level: (N,) levels in [0, num_levels).
            streams: (N,) integer keys: environment i then draws everything random of this
                and its later episodes (spawn, variant, commands, latency, pushes, noise)
                from its own generator ``default_rng([cfg.seed, STREAM_SALT, streams[i]])``
                (needs ``terrain.curriculum`` off). None: every draw comes from the shared
                generator ``rng`` (the default; collection).
        Returns:
            the first observation of every environment.
        """
        if type_idx is not None or level is not None:
            self.set_tiles(self.type_idx if type_idx is None else type_idx,
                           self.level if level is None else level)
        self.streams = None if streams is None else self._make_streams(streams)
        #: the sourced sensors' per-environment generators (their own, as ``seed_sources``)
        self._source_streams = None if streams is None else [
            np.random.default_rng([self.cfg.seed, STREAM_SALT, int(k), SOURCE_SALT])
            for k in np.asarray(streams, dtype=np.int64)]
        self._reset_ids(np.arange(self.num_envs))
        self._needs_reset = False
        self.last_obs = self._observe()
        return self.last_obs

    def restart(self, ids: np.ndarray) -> dict[str, np.ndarray]:
        """Start new episodes for envs ``ids`` now, between steps, as the auto-reset does
        (spawn, variant, command, latency, buffers); returns their first observation (rows
        of ``ids``), also written into ``last_obs``.

        Args:
            ids: environment indices.
        """
        ids = np.asarray(ids, dtype=np.int64)
        self._reset_ids(ids)
        # The latency history holds each reset env's (noisy) first frame; observing it here
        # ends the "just reset" state, so the next step appends to it.
        first = self._obs_dict(self._hist[ids, -1], {k: v[ids] for k, v in self.meas.items()},
                               ids)
        self._hist_fresh = np.zeros(0, dtype=np.int64)
        for k, v in first.items():
            self.last_obs[k][ids] = v
        return first

    @property
    def step_end_state(self) -> np.ndarray:
        """(N, nstate) physics state at the end of the last step, before any auto-reset
        replaced it by a spawn (what ended an episode, for rendering)."""
        return self._out_state[:, -1]

    def _make_streams(self, keys: np.ndarray) -> list[np.random.Generator]:
        if self.cfg.terrain.curriculum:
            raise ValueError("per-environment streams need terrain.curriculum=False (the "
                             "curriculum's level changes draw from the shared generator)")
        keys = np.asarray(keys, dtype=np.int64)
        if keys.shape != (self.num_envs,):
            raise ValueError(f"streams has shape {keys.shape}, expected ({self.num_envs},)")
        return [np.random.default_rng([self.cfg.seed, STREAM_SALT, int(k)]) for k in keys]

    def set_tiles(self, type_idx: np.ndarray, level: np.ndarray) -> None:
        """Pin terrain type and level per environment (applied at each env's next reset)."""
        t = np.broadcast_to(np.asarray(type_idx, dtype=np.int64), (self.num_envs,)).copy()
        lv = np.broadcast_to(np.asarray(level, dtype=np.int64), (self.num_envs,)).copy()
        self.terrain.tile_center(t, lv)  # validates, raising with the bad value
        self.type_idx, self.level = t, lv

    def step(self, action: np.ndarray) -> StepResult:
        """Apply (N, 12) actions for one control step.

        Args:
            action: offsets from the default pose in units of ``action_scale``.
        """
        if self._needs_reset:
            raise RuntimeError("call reset() before step()")
        a = self._check_action(action)
        self.last_action[:] = self.action
        self.action[:] = a
        target = self._default_pose + self.cfg.control.action_scale * a
        self._control[:] = target[:, None, :]
        t_before = self.state[:, 0].copy()
        self._runner.rollout(self._models, self._datas, self.state, self._control,
                             control_spec=mujoco.mjtState.mjSTATE_CTRL.value, skip_checks=True,
                             nstep=self.cfg.control.decimation, state=self._out_state,
                             sensordata=self._out_sens)
        self.state[:] = self._out_state[:, -1]
        # MuJoCo resets an unstable MjData itself (time restarts at 0), so a blow-up shows
        # as a clock that did not advance by one control step, or as non-finite values.
        expected = t_before + self.cfg.control.decimation * self.cfg.control.sim_dt
        blown = ~np.isfinite(self.state).all(axis=1)
        blown |= np.abs(self.state[:, 0] - expected) > 0.5 * self.cfg.control.sim_dt
        if blown.any():
            self.state[blown] = self._template
        self.meas = self._measure(self.state, self._out_sens)
        return self._finish_step(blown)

    # ------------------------------------------------------------------ internals
    def _check_action(self, action: np.ndarray) -> np.ndarray:
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (self.num_envs, self.robot.num_joints):
            raise ValueError(f"action has shape {a.shape}, expected "
                             f"({self.num_envs}, {self.robot.num_joints})")
        bad = ~np.isfinite(a).all(axis=1)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"action for env {i} is not finite: {a[i].tolist()}")
        lim = self.cfg.control.clip_actions
        return np.clip(a, -lim, lim)

    def _finish_step(self, blown: np.ndarray) -> StepResult:
        m, cfg = self.meas, self.cfg
        self.commands.update_yaw_rate(m["yaw"])
        fell = ((m["trunk_contact"] > self.robot.contact_threshold)
                | (m["gravity"][:, 2] > cfg.fall_gravity_z))
        rew = self._rewards(m, fell)
        for k in rew:
            rew[k][blown] = 0.0
        self.episode_step += 1
        self.episode_return += rew["total"]
        terminated = (fell & ~blown) | blown
        truncated = (self.episode_step >= self.max_steps) & ~terminated
        reason = np.zeros(self.num_envs, dtype=np.int64)
        reason[fell] = 1
        reason[truncated] = 2
        reason[blown] = 3
        final = self._episode_summary(m)
        done_ids = np.flatnonzero(terminated | truncated)
        np.add.at(self.resets_by_reason, reason[done_ids], 1)
        if cfg.terrain.curriculum and len(done_ids):
            self.level[done_ids] = update_levels(
                self.level[done_ids], final["distance"][done_ids],
                np.linalg.norm(self.commands.command[done_ids, :2], axis=1),
                cfg.episode_length_s, self.rng, cfg.terrain.num_levels,
                tile_size=cfg.terrain.tile_size)
        self._resample_commands()
        self._push()
        self.meas_before_reset = {k: m[k].copy() for k in ("base_lin_vel", "base_ang_vel",
                                                             "base_pos")}
        if len(done_ids):
            # Last observation of the finished episodes (no latency), before the reset:
            # rows of ``final_obs`` belong to ``final_ids``.
            sub = {k: v[done_ids] for k, v in m.items()}
            self.final_obs = self._obs_dict(self._proprio(sub, done_ids), sub, done_ids)
            self.final_ids = done_ids
            self._reset_ids(done_ids)
        obs = self.last_obs = self._observe()
        metrics = {k: v for k, v in rew.items()}
        return StepResult(obs, rew["total"], metrics, terminated, truncated, reason, final)

    def _episode_summary(self, m: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {
            "type_idx": self.type_idx.copy(), "level": self.level.copy(),
            "length": self.episode_step.copy(), "return": self.episode_return.copy(),
            "distance": np.linalg.norm(m["base_pos"][:, :2] - self.spawn_xy, axis=1),
            "variant": self.variant.copy(),
        }

    def _rewards(self, m: dict[str, np.ndarray], fell: np.ndarray) -> dict[str, np.ndarray]:
        contact = m["foot_contact"] > 0.5
        self.air_time += self.dt
        first = contact & ~self.last_contact
        inputs = RewardInputs(
            lin_vel=m["base_lin_vel"], ang_vel=m["base_ang_vel"], command=self.commands.command,
            torques=m["torques"], joint_pos=m["joint_pos"], joint_vel=m["joint_vel"],
            last_joint_vel=self.last_joint_vel, action=self.action, last_action=self.last_action,
            leg_collisions=m["leg_collisions"], first_contact=first, air_time=self.air_time,
            soft_limits=self.soft_limits, dt=self.dt, sigma=self.cfg.rewards.tracking_sigma,
            air_time_target=self.cfg.rewards.air_time_target, fell=fell)
        out = compute_rewards(self.cfg.rewards, inputs)
        self.air_time[contact] = 0.0
        self.last_contact = contact
        self.last_joint_vel = m["joint_vel"].copy()
        return out

    def _resample_commands(self) -> None:
        every = max(1, int(round(self.cfg.commands.resample_s / self.dt)))
        ids = np.flatnonzero((self.episode_step % every == 0) & (self.episode_step > 0))
        if self.streams is None:
            self.commands.resample(ids, self.rng)
        else:
            for i in ids:
                self.commands.resample(np.array([i]), self.streams[i])

    def _push(self) -> None:
        rc = self.cfg.randomization
        if not (rc.enabled and rc.push_interval_s > 0 and rc.push_max_vel > 0):
            return
        every = max(1, int(round(rc.push_interval_s / self.dt)))
        ids = np.flatnonzero((self.episode_step + self.push_step) % every == every - 1)
        if len(ids):
            v, lim = self.layout.base_linvel, rc.push_max_vel
            if self.streams is None:
                kick = self.rng.uniform(-lim, lim, (len(ids), 2))
            else:
                kick = np.array([self.streams[i].uniform(-lim, lim, 2) for i in ids])
            self.state[ids, v.start:v.start + 2] += kick

    def _reset_ids(self, ids: np.ndarray) -> None:
        """New episodes for ``ids``, from the shared generator or each one's own stream."""
        if self.streams is None:
            self._reset_rows(ids, self.rng)
        else:
            if not self.meas:  # rows are measured one at a time: start from the whole batch
                self.state[:] = self._template
                self.meas = self._measure(self.state, np.zeros((self.num_envs, 1,
                                                                self.model.nsensordata)))
            for i in ids:
                self._reset_rows(np.array([i]), self.streams[i])
        self._hist_fresh = np.asarray(ids)

    def _reset_rows(self, ids: np.ndarray, rng: np.random.Generator) -> None:
        """New episodes for ``ids`` drawn from ``rng``: spawn state, variant, command,
        latency, buffers."""
        n, cfg = len(ids), self.cfg
        centre = self.terrain.tile_center(self.type_idx[ids], self.level[ids], rng=rng)
        xy = centre[:, :2] + rng.uniform(-cfg.spawn_offset, cfg.spawn_offset, (n, 2))
        yaw = rng.uniform(-np.pi, np.pi, n)
        st = np.tile(self._template, (n, 1))
        lay = self.layout
        ground = self.terrain.height_at(xy[:, None, :] + self._footprint[None]).max(axis=1)
        st[:, lay.base_pos] = np.column_stack([xy, ground + self.robot.spawn_height])
        st[:, lay.base_quat] = yaw_quat(yaw)
        self.state[ids] = st
        self.variant[ids] = rng.integers(0, len(self.pool), n)
        for i, v in zip(ids, self.variant[ids]):
            self._models[i] = self.pool[v]
        self.commands.resample(ids, rng)
        self.latency[ids] = rng.integers(0, self._lat + 1, n)
        self.push_step[ids] = rng.integers(0, 1 << 30, n)
        self.spawn_xy[ids] = xy
        for buf in (self.action, self.last_action, self.last_joint_vel, self.air_time):
            buf[ids] = 0.0
        self.last_contact[ids] = False
        self.episode_step[ids] = 0
        self.episode_return[ids] = 0.0
        sens = np.zeros((n, 1, self.model.nsensordata))
        fresh = self._measure(self.state[ids], sens, ids)
        if not self.meas:
            self.meas = fresh
        else:
            for k, v in fresh.items():
                self.meas[k][ids] = v
        self.commands.update_yaw_rate(fresh["yaw"], ids)
        self._hist[ids] = self._proprio(fresh, ids)[:, None, :]

    def seed_sources(self, seed: int) -> None:
        """Reseed the noise of the sensors read from a measurement (registry ``source``, e.g.
        ``height_map``): a stream of its own, so such a sensor changes no other draw (with
        ``reset(streams=...)`` each environment has its own such stream too)."""
        self._source_rng = np.random.default_rng([seed, SOURCE_SALT])

    def _measure(self, state: np.ndarray, sens: np.ndarray,
                 ids: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Physical quantities from states (N, nstate) and substep sensors (N, d, ns)."""
        lay = self.layout
        ids = np.arange(self.num_envs) if ids is None else ids
        pos, quat = state[:, lay.base_pos], state[:, lay.base_quat]
        quat = quat / np.linalg.norm(quat, axis=1, keepdims=True)
        rot = quat_to_mat(quat)
        yaw = yaw_of(quat)
        c, s = np.cos(yaw), np.sin(yaw)
        px, py = self._scan_points[:, 0], self._scan_points[:, 1]
        scan_xy = np.stack([pos[:, :1] + c[:, None] * px - s[:, None] * py,
                            pos[:, 1:2] + s[:, None] * px + c[:, None] * py], axis=-1)
        heights = self.terrain.height_at(scan_xy)                       # (N, 187)
        below = self.terrain.height_at(pos[:, :2])
        optional = {} if self._accel is None else {"accel": sens[:, :, self._accel].mean(axis=1)}
        return optional | {
            "base_pos": pos, "yaw": yaw, "orientation": quat,
            "joint_pos": state[:, lay.joint_pos], "joint_vel": state[:, lay.joint_vel],
            "base_lin_vel": world_to_body(rot, state[:, lay.base_linvel]),
            "base_ang_vel": state[:, lay.base_angvel].copy(),
            "gravity": -rot[:, 2, :],
            "foot_contact": (sens[:, :, robot.SENS_FOOT].max(axis=1)
                             > self.robot.contact_threshold).astype(np.float64),
            "trunk_contact": sens[:, -1, robot.SENS_TRUNK],
            "leg_collisions": sens[:, -1, robot.SENS_LEG_COLLISION],
            "torques": sens[:, :, robot.SENS_TORQUE].mean(axis=1),
            "height_scan": heights - pos[:, 2:3],
            "base_height": (pos[:, 2] - below)[:, None],
            "dynamics": self.pool_params[self.variant[ids]],
        }

    def _proprio(self, m: dict[str, np.ndarray], ids: np.ndarray) -> np.ndarray:
        """Noisy proprioception (len(ids), 45) of rows ``ids`` of ``m``."""
        if self.streams is not None:  # one draw per row from its environment's stream
            x = np.concatenate([m["base_ang_vel"] if k == "ang_vel" else m[k] for k in PROPRIO],
                               axis=1)
            if self._noise_width.any():
                u = np.stack([self.streams[i].random(x.shape[1]) for i in ids])
                x = x + (2.0 * u - 1.0) * self._noise_width
            return x.astype(np.float32)
        parts = []
        for k in PROPRIO:
            x = m["base_ang_vel"] if k == "ang_vel" else m[k]
            w = self._noise[k]
            if w > 0:
                x = x + self.rng.uniform(-w, w, x.shape)
            parts.append(x)
        return np.concatenate(parts, axis=1).astype(np.float32)

    def _observe(self) -> dict[str, np.ndarray]:
        """Registry-named observations (float32) of the current state, with noise and latency."""
        m, n = self.meas, self.num_envs
        fresh = self._proprio(m, np.arange(n))
        if self._lat:
            keep = np.ones(n, dtype=bool)
            keep[self._hist_fresh] = False   # just reset: history already holds this frame
            self._hist[keep] = np.roll(self._hist[keep], -1, axis=1)
            self._hist[keep, -1] = fresh[keep]
            delayed = self._hist[np.arange(n), self._lat - self.latency]
        else:
            delayed = fresh
        self._hist_fresh = np.zeros(0, dtype=np.int64)
        return self._obs_dict(delayed, m)

    def _obs_dict(self, proprio: np.ndarray, m: dict[str, np.ndarray],
                  ids: np.ndarray | slice = slice(None)) -> dict[str, np.ndarray]:
        obs: dict[str, np.ndarray] = {}
        start = 0
        for k in PROPRIO:
            d = SENSORS[k].dim
            obs[k] = proprio[:, start:start + d]
            start += d
        obs["command"] = self.commands.command[ids].astype(np.float32)
        obs["last_action"] = self.action[ids].astype(np.float32)
        for k in ("base_lin_vel", "base_ang_vel", "orientation", "base_height", "height_scan",
                  "dynamics"):
            obs[k] = m[k].astype(np.float32)
        for spec in SENSORS.values():  # sensors read from a measurement (e.g. height_map)
            if spec.source and spec.name in self._offered:
                x = m[spec.source]
                w = spec.noise * self.cfg.noise.scale if self.cfg.noise.enabled else 0.0
                if w > 0 and self._source_streams is not None:  # one draw per row, own stream
                    rows = np.arange(self.num_envs)[ids]
                    u = np.stack([self._source_streams[i].random(x.shape[1]) for i in rows])
                    x = x + (2.0 * u - 1.0) * w
                elif w > 0:
                    x = x + self._source_rng.uniform(-w, w, x.shape)
                obs[spec.name] = x.astype(np.float32)
        return {k: v for k, v in obs.items() if k in self._offered}  # what the robot offers

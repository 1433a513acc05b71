"""Gymnasium views of the batched simulator, registered as ``msta/A1-v0`` and ``msta/Go1-v0``.

``import msta.collect.sim`` registers the ids, the way Gymnasium's plugin packages do
(``import ale_py``, ``import gymnasium_robotics``; ``gym.register_envs(msta.collect.sim)`` keeps
linters from dropping the import, ``gym.make("msta.collect.sim:msta/A1-v0")`` does the import
itself). The package is what simulator users import anyway, and the registration names its
entry points as strings, so it costs only Gymnasium's import: MuJoCo and this module load
when an env is made::

    import gymnasium as gym
    import msta.collect.sim  # noqa: F401  (registers msta/A1-v0, msta/Go1-v0)

    env = gym.make("msta/A1-v0", render_mode="rgb_array")           # MstaEnv, one robot
    envs = gym.make_vec("msta/A1-v0", num_envs=64,
                        vectorization_mode="vector_entry_point")    # MstaVectorEnv, batched
    go1 = gym.make("msta/Go1-v0")                                   # the Go1 (robot="go1")

Both take ``cfg`` (an ``EnvConfig``), ``sensors``, ``actions`` and ``robot`` as keyword
arguments. ``msta/A1-v0`` simulates ``cfg.robot`` (the A1 by default; any robot description
runs there); ``msta/Go1-v0`` is the same views with ``robot="go1"`` (a ``cfg`` naming another
robot than the default is refused).

Observations are a ``Dict`` space keyed by registry sensor name (``msta_data/sensors.py``),
the names the simulator, the dataset columns and the policies use. By default they are the
student's sensors the robot offers (``STUDENT_SENSORS``: on the A1 the paper's 49 scalars,
``FlattenObservation`` makes them one (49,) vector; the Go1 offers no ``foot_contact``: 45);
``sensors=`` names others too, e.g. ``sensors=(*STUDENT_SENSORS, *PRIVILEGED_SENSORS)`` for a
teacher's inputs or ``"height_map"``. A sensor the robot does not offer (its description's
``sensors``) is refused in one line when the env is made.
Every ``Box`` states a finite range (the joint range from the robot model, the config's
command and randomization ranges, measured ranges where the physics has none: ``spaces.py``)
and readings are clipped to it.

Actions (``actions=``): "normalized" (default), a (12,) vector in [-1, 1]: 0 is the default
pose, +1 and -1 a joint's upper and lower stop, linear on each side; it is turned into the
simulator action of the same joint target, so the physics is the simulator's.
``last_action`` is then reported in the same normalized units. "simulator": the simulator's
and the datasets' own action (offsets from the default pose in units of ``action_scale``,
clipped to +-``clip_actions``), as msta's students output it. The time limit is the simulator's own
(``EnvConfig.episode_length_s``, reported as ``truncated``), so the id adds no ``TimeLimit``.
The simulator draws from the env's ``np_random`` (first ``cfg.seed``'s generator);
``reset(seed=s)`` reseeds it and redraws the terrain tiles, so a seeded reset does not depend
on earlier episodes (the curriculum moves tiles).

Autoreset of ``MstaVectorEnv`` (``metadata["autoreset_mode"]``), chosen by ``autoreset_mode``:

- ``NEXT_STEP`` (default; Gymnasium >= 1.0's default, which its vector wrappers assume): the
  step that ends an episode returns that episode's last observation (the simulator's
  ``final_obs``); the next step ignores that env's action and returns its new episode's
  first observation with reward 0 and ``terminated``/``truncated`` False. ``QuadrupedEnv``
  resets finished envs inside its own ``step`` and steps every env on the next call, so the
  physics step it takes there for a resetting env is thrown away: the env is reset again
  right after it (``MstaVectorEnv._restart``, through the simulator's own reset), and an end
  that step reached is taken off ``sim.resets_by_reason`` and the curriculum level. So the
  contract holds exactly: every episode starts at a spawn, its first action is the one chosen
  from its first observation, and it lasts the simulator's full ``max_episode_steps``. The
  price: one wasted control step and one extra spawn draw per episode.
- ``SAME_STEP`` (the simulator's own behaviour): a finished env's returned observation is the
  next episode's first one; the last one is in ``infos["final_obs"]`` and that step's infos
  in ``infos["final_info"]`` (masks ``_final_obs``, ``_final_info``).

``MstaEnv`` has no autoreset: the step that ends an episode returns its last observation, and
the next call must be ``reset()``. ``gym.make_vec(..., vectorization_mode="sync")`` also works
(one simulator per env, slower).

Step infos: ``reason`` (one of ``msta.collect.sim.env.REASONS``), ``lin_vel_tracking`` and
``ang_vel_tracking`` (the paper's metrics), each with a ``_<key>`` mask that is False for
envs being reset by a NEXT_STEP step.

``render_mode="rgb_array"``: ``render()`` draws the robot with ``render.py``'s tracking
camera (``MstaVectorEnv``: one frame per env). Until an ended episode is reset, it shows the
state that ended it. Headless Linux renders through EGL: ``import msta.collect.sim`` sets
``MUJOCO_GL=egl`` unless it is set (docs/simulator.md, "Rendering without a display", says
which backends fail where and why).
"""

from __future__ import annotations

import atexit
import dataclasses
from collections.abc import Sequence
from dataclasses import replace
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium.envs.registration import EnvSpec
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from msta.collect.sim.env import REASONS, QuadrupedEnv, StepResult
from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.render import PatchRenderer
from msta.collect.sim.robot import joint_limits
from msta.collect.sim.spaces import ACTION_MODES, ActionMap, action_bounds, observation_bounds
from msta.collect.sim.terrain import sample_initial
from msta.data.robot import NUM_JOINTS, RobotDescription
from msta.data.sensors import STUDENT_SENSORS, get

RESET_OPTIONS = ("type_idx", "level")
INFO_KEYS = ("reason", "lin_vel_tracking", "ang_vel_tracking")


def view_sensors(robot: RobotDescription, sensors: Sequence[str] | None) -> tuple[str, ...]:
    """The sensors a view exposes: ``sensors``, each one the robot offers, or by default the
    student's (``STUDENT_SENSORS``) that the robot offers (on the A1 all of them; on the Go1
    all but ``foot_contact``).

    Args:
        robot: the simulated robot's description (its ``sensors``).
        sensors: registry names, or None (empty) for the default.

    Raises:
        KeyError: a name the registry does not know (the message lists the known ones).
        ValueError: (one line) a sensor the robot does not offer.
    """
    if not sensors:
        return tuple(s for s in STUDENT_SENSORS if s in robot.sensors)
    names = tuple(sensors)
    for s in names:
        get(s)  # KeyError naming the unknown sensor
    missing = [s for s in names if s not in robot.sensors]
    if missing:
        raise ValueError(f"robot {robot.name!r} does not offer {', '.join(missing)} "
                         f"(sensors=); it offers {', '.join(robot.sensors)}")
    return names


def robot_config(cfg: EnvConfig | None, robot: str | None) -> EnvConfig:
    """``cfg`` (default ``EnvConfig()``) simulating ``robot`` when one is given (an id's
    robot: ``msta/Go1-v0`` passes ``"go1"``); a ``cfg`` naming yet another robot is refused in
    one line."""
    cfg = cfg or EnvConfig()
    if robot is None or cfg.robot == robot:
        return cfg
    if cfg.robot != EnvConfig.robot:
        raise ValueError(f"robot={robot!r} but cfg.robot={cfg.robot!r}: give one of them (an "
                         "id's robot: make msta/A1-v0 with cfg.robot instead)")
    return replace(cfg, robot=robot)


class _View:
    """What both views share: the simulator, the spaces, seeding and the renderer."""

    sim: QuadrupedEnv
    render_mode: str | None

    def _setup(self, cfg: EnvConfig, sensors: tuple[str, ...] | None, render_mode: str | None,
               width: int, height: int, actions: str) -> gym.spaces.Dict:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode={render_mode!r}; the msta envs render 'rgb_array' "
                             "only")
        if width < 1 or height < 1:
            raise ValueError(f"render size {width}x{height} must be positive")
        if actions not in ACTION_MODES:
            raise ValueError(f"actions={actions!r}; expected one of {list(ACTION_MODES)}")
        self.sensors = view_sensors(cfg.robot_description, sensors)
        self.sim = QuadrupedEnv(cfg)
        self.actions = actions
        self._map = ActionMap(joint_limits(self.sim.model), self.sim.cfg.control.action_scale,
                              self.sim.robot.default_pose)
        self._bounds = observation_bounds(self.sim, actions)
        self.render_mode, self._size = render_mode, (height, width)
        self._renderer: Any = None
        self.shadows = True  # frames with shadows (set before the first render)
        self._final_state = np.zeros_like(self.sim.state)   # see _keep_final
        self._ended = np.zeros(self.sim.num_envs, dtype=bool)
        self.metadata = {**type(self).metadata, "render_fps": int(round(1.0 / cfg.dt))}
        self._np_random, self._np_random_seed = self.sim.rng, cfg.seed
        return gym.spaces.Dict({s: gym.spaces.Box(*self._bounds[s], dtype=np.float32)
                                for s in self.sensors})

    @property
    def spec(self) -> EnvSpec | None:
        """The spec ``gym.make`` gave (None without it), its ``max_episode_steps`` the
        simulator's own time limit in control steps (the env truncates there itself)."""
        return getattr(self, "_spec", None)

    @spec.setter
    def spec(self, value: EnvSpec | None) -> None:
        self._spec = value if value is None else dataclasses.replace(
            value, max_episode_steps=self.sim.max_steps)

    def _action_box(self) -> gym.spaces.Box:
        low, high = action_bounds(self.sim, self.actions)
        return gym.spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)

    def _to_sim(self, a: np.ndarray) -> np.ndarray:
        """(..., 12) actions of this view -> the simulator's (a wrong shape passes through
        to the simulator's own one-line error)."""
        if self.actions == "simulator" or a.shape[-1:] != (NUM_JOINTS,):
            return a
        return self._map.to_sim(a)

    def _reset_sim(self, seed: int | None, options: dict[str, Any] | None,
                   rng: np.random.Generator) -> dict[str, np.ndarray]:
        """Reset every simulated env from ``rng`` (the view's ``np_random``)."""
        options = dict(options or {})
        unknown = sorted(set(options) - set(RESET_OPTIONS))
        if unknown:
            raise ValueError(f"unknown reset option(s) {unknown}; expected some of {RESET_OPTIONS}")
        sim, cfg = self.sim, self.sim.cfg
        sim.rng = rng
        if seed is not None:
            sim.seed_sources(seed)
            t, lv = sample_initial(sim.num_envs, rng, cfg.terrain, list(cfg.type_weights) or None)
            options.setdefault("type_idx", t)
            options.setdefault("level", lv)
        return sim.reset(options.get("type_idx"), options.get("level"))

    def _select(self, obs: dict[str, np.ndarray], rows: Any = slice(None)) -> dict[str, np.ndarray]:
        """This view's sensors of simulator observations: ``last_action`` in this view's
        action units, every reading clipped to its space (``spaces.py``)."""
        out = {}
        for s in self.sensors:
            x = obs[s][rows]
            if s == "last_action" and self.actions == "normalized":
                x = self._map.from_sim(x)
            out[s] = np.clip(x, *self._bounds[s]).astype(np.float32)
        return out

    def _keep_final(self, done: np.ndarray) -> None:
        """Mark the envs whose episode ended this step; until they reset, ``render()`` shows
        the physics state that ended it (the simulator has already replaced it by a spawn)."""
        self._ended = done.copy()
        if done.any():
            last = self.sim.step_end_state[done]  # the step's last physics state (pre-reset)
            ok = np.isfinite(last).all(axis=1)    # a blown-up one: show the reset state
            self._final_state[done] = np.where(ok[:, None], last, self.sim.state[done])

    def _render_state(self, env_id: int) -> np.ndarray:
        """The full-physics state ``render()`` shows for env ``env_id``."""
        return self._final_state[env_id] if self._ended[env_id] else self.sim.state[env_id]

    def _frame(self, env_id: int) -> np.ndarray:
        """(H, W, 3) uint8 picture of env ``env_id`` (render.py's tracking camera, the
        terrain around the robot: :class:`~msta.collect.sim.render.PatchRenderer`)."""
        if not self.sim.last_obs:
            raise RuntimeError("call reset() before render()")
        if self._renderer is None:
            h, w = self._size
            self._renderer = PatchRenderer(self.sim.model, self.sim.terrain,
                                           self.sim.cfg.collision, h, w, shadows=self.shadows,
                                           robot=self.sim.robot)
            # MuJoCo's EGL backend terminates its display at exit (an atexit hook registered
            # with the first context); a renderer freed after that prints EGL errors, so an
            # env left open closes its renderer at exit, before that hook runs.
            atexit.register(self._renderer.close)
        return self._renderer.render(self._render_state(env_id))

    def _close_renderer(self) -> None:
        if getattr(self, "_renderer", None) is not None:
            atexit.unregister(self._renderer.close)
            self._renderer.close()
            self._renderer = None

    def __del__(self) -> None:
        self._close_renderer()


def _infos(res: StepResult, stepped: np.ndarray) -> dict[str, Any]:
    """Batched step infos; rows where ``stepped`` is False (being reset) are masked out."""
    reason = np.array([REASONS[i] for i in res.reason])
    reason[~stepped] = REASONS[0]
    infos: dict[str, Any] = {"reason": reason}
    for k in INFO_KEYS[1:]:
        infos[k] = np.where(stepped, res.metrics[k], 0.0)
    for k in INFO_KEYS:
        infos[f"_{k}"] = stepped.copy()
    return infos


class MstaEnv(_View, gym.Env):
    """One simulated robot as a ``gymnasium.Env`` (``gym.make("msta/A1-v0")``,
    ``gym.make("msta/Go1-v0")``).

    After an episode ends, call ``reset()`` (stepping on raises): the observation of the
    ending step is the episode's last one (the simulator's ``final_obs``).

    Args:
        cfg: simulator config; ``num_envs`` and ``nthread`` are set to 1.
        sensors: registry sensors to expose, each one the robot offers (default: the
            student's, ``STUDENT_SENSORS``, the robot offers; name privileged ones or
            ``height_map`` to get them too).
        render_mode: None or "rgb_array" (``render()`` returns a (height, width, 3) uint8 frame).
        width, height: render size in pixels.
        actions: "normalized" (default: [-1, 1] per joint, 0 the default pose, +-1 the joint
            stops) or "simulator" (the simulator's and the datasets' action, +-clip_actions).
        robot: the robot to simulate in place of ``cfg.robot``'s (``msta/Go1-v0`` passes
            ``"go1"``; a ``cfg`` naming another robot than the default is refused).
    """

    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(self, cfg: EnvConfig | None = None, sensors: tuple[str, ...] | None = None,
                 render_mode: str | None = None, width: int = 480, height: int = 360,
                 actions: str = "normalized", robot: str | None = None) -> None:
        cfg = replace(robot_config(cfg, robot), num_envs=1, nthread=1)
        self.observation_space = self._setup(cfg, sensors, render_mode, width, height, actions)
        self.action_space = self._action_box()

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Start an episode. ``seed`` reseeds the simulator; ``options`` may hold ``type_idx``
        and ``level`` to pin the terrain tile."""
        super().reset(seed=seed)
        obs = self._reset_sim(seed, options, self.np_random)
        self._ended[:] = False
        return self._select(obs, 0), {}

    def step(self, action: np.ndarray):
        """One control step; returns (obs, reward, terminated, truncated, info)."""
        if self._ended[0]:
            raise RuntimeError("the episode has ended; call reset() before step()")
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (NUM_JOINTS,):
            raise ValueError(f"action has shape {a.shape}, expected ({NUM_JOINTS},)")
        res = self.sim.step(self._to_sim(a[None]))
        self._keep_final(res.done)
        obs = self._select(self.sim.final_obs if res.done[0] else res.obs, 0)
        info = {k: v[0].item() for k, v in _infos(res, np.ones(1, dtype=bool)).items()
                if not k.startswith("_")}
        return obs, float(res.reward[0]), bool(res.terminated[0]), bool(res.truncated[0]), info

    def render(self) -> np.ndarray | None:
        """The robot as a (height, width, 3) uint8 frame (None without ``render_mode``)."""
        if self.render_mode is None:
            gym.logger.warn("render() needs render_mode='rgb_array' when the env is made")
            return None
        return self._frame(0)

    def close(self) -> None:
        self._close_renderer()


class MstaVectorEnv(_View, VectorEnv):
    """All simulated robots as one Gymnasium ``VectorEnv`` (see the module docstring).

    Args:
        cfg: simulator config (``cfg.num_envs`` environments).
        sensors: registry sensors to expose (default: the student's the robot offers), as
            ``MstaEnv``'s.
        num_envs: overrides ``cfg.num_envs`` (``gym.make_vec`` always passes it).
        autoreset_mode: ``AutoresetMode.NEXT_STEP`` (default) or ``SAME_STEP`` (or their
            string values "NextStep", "SameStep").
        render_mode: None or "rgb_array" (``render()`` returns one frame per env).
        width, height: render size in pixels.
        actions: "normalized" (default) or "simulator", as ``MstaEnv``'s.
        robot: the robot to simulate in place of ``cfg.robot``'s, as ``MstaEnv``'s.
    """

    metadata: ClassVar[dict] = {"autoreset_mode": AutoresetMode.NEXT_STEP,
                                "render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(self, cfg: EnvConfig | None = None, sensors: tuple[str, ...] | None = None,
                 num_envs: int | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                 render_mode: str | None = None, width: int = 480, height: int = 360,
                 actions: str = "normalized", robot: str | None = None) -> None:
        modes = (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)
        mode = next((m for m in modes if autoreset_mode in (m, m.value)), None)
        if mode is None:
            raise ValueError(f"autoreset_mode={autoreset_mode!r}; expected one of "
                             f"{[m.value for m in modes]}")
        cfg = robot_config(cfg, robot)
        if num_envs is not None:
            cfg = replace(cfg, num_envs=num_envs)
        self.single_observation_space = self._setup(cfg, sensors, render_mode, width, height,
                                                    actions)
        self.metadata["autoreset_mode"] = self.autoreset_mode = mode
        self.num_envs = self.sim.num_envs
        self.single_action_space = self._action_box()
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset all envs. ``seed`` reseeds the simulator's generator; ``options`` may hold
        ``type_idx`` and ``level`` arrays to pin terrain tiles."""
        super().reset(seed=seed)
        obs = self._reset_sim(seed, options, self.np_random)
        self._ended[:] = False
        return self._select(obs), {}

    def step(self, actions: np.ndarray):
        """One control step of every env; returns batched (obs, reward, terminated,
        truncated, infos) in the mode of ``metadata["autoreset_mode"]``."""
        restart = self._ended.copy()
        a = np.asarray(actions, dtype=np.float64)
        if restart.any() and a.shape == (self.num_envs, NUM_JOINTS):
            a = np.where(restart[:, None], 0.0, a)  # ignored: these envs are being reset
        level = self.sim.level.copy()
        res = self.sim.step(self._to_sim(a))
        obs = self._select(res.obs)
        reward = res.reward.astype(np.float32)
        term, trunc = res.terminated.copy(), res.truncated.copy()
        infos = _infos(res, ~restart)
        if self.autoreset_mode == AutoresetMode.SAME_STEP:
            done = term | trunc
            if done.any():
                infos["final_obs"] = self._final_obs(done)
                infos["_final_obs"] = done.copy()
                infos["final_info"] = {**{k: infos[k].copy() for k in INFO_KEYS},
                                       **{f"_{k}": done.copy() for k in INFO_KEYS}}
                infos["_final_info"] = done.copy()
            return obs, reward, term, trunc, infos
        if restart.any():
            ids = np.flatnonzero(restart)
            fresh = self._restart(ids, res, level)
            for s in self.sensors:
                obs[s][ids] = fresh[s]
            reward[ids], term[ids], trunc[ids] = 0.0, False, False
        done = term | trunc
        if done.any():
            final = self._final_obs(done)
            for s in self.sensors:
                obs[s][done] = final[s][done]
        self._keep_final(done)
        return obs, reward, term, trunc, infos

    def _final_obs(self, done: np.ndarray) -> dict[str, np.ndarray]:
        """(N, dim) per sensor: the simulator's last observation of the episodes ending now
        (rows where ``done``), zeros elsewhere."""
        ids = np.flatnonzero(done)
        rows = np.searchsorted(self.sim.final_ids, ids)  # final_ids: sorted ids done this step
        out = {s: np.zeros((self.num_envs, get(s).dim), dtype=np.float32) for s in self.sensors}
        last = self._select(self.sim.final_obs, rows)
        for s in self.sensors:
            out[s][ids] = last[s]
        return out

    def _restart(self, ids: np.ndarray, res: StepResult, level: np.ndarray
                 ) -> dict[str, np.ndarray]:
        """Put envs ``ids`` back at a fresh spawn after the step that ignored their action.

        ``QuadrupedEnv`` reset them in the previous step and has just stepped their new
        episode; that step is undone by resetting them again the way the simulator resets
        (``QuadrupedEnv.restart``). If the thrown-away step ended one of them,
        its end is taken off ``resets_by_reason`` and its curriculum level restored.
        Returns their first observation (rows of ``ids``), also written to ``sim.last_obs``.
        """
        sim = self.sim
        ended = ids[res.done[ids]]
        np.subtract.at(sim.resets_by_reason, res.reason[ended], 1)
        sim.level[ended] = level[ended]
        return self._select(sim.restart(ids))

    def render(self) -> tuple[np.ndarray, ...] | None:
        """One (height, width, 3) uint8 frame per env (None without ``render_mode``)."""
        if self.render_mode is None:
            gym.logger.warn("render() needs render_mode='rgb_array' when the env is made")
            return None
        return tuple(self._frame(i) for i in range(self.num_envs))

    def render_first(self, count: int) -> tuple[np.ndarray, ...]:
        """:meth:`render` of the first ``count`` envs, a gray frame for each other one (a
        caller that keeps only those, as lerobot-eval does, pays for no other)."""
        gray = np.full((*self._size, 3), 128, np.uint8)
        return tuple(self._frame(i) if i < count else gray for i in range(self.num_envs))

    def close_extras(self, **kwargs: Any) -> None:
        self._close_renderer()

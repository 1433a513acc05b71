"""Configuration of the batched simulator (``msta.collect.sim.env.QuadrupedEnv``).

``EnvConfig.robot`` names the robot the simulator builds (a shipped robot or a spec file,
docs/robots.md); its description is loaded and checked when the config is constructed.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field, fields, replace

from msta.collect.sim.commands import CommandConfig
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.rewards import RewardConfig
from msta.collect.sim.robot import check_collision_set
from msta.collect.sim.terrain import TerrainConfig
from msta.data.checks import check_finite_fields, check_number
from msta.data.robot import RobotDescription, load_robot
from msta.data.sensors import JOINT_NAMES, LEGS

#: The most environments one simulator steps (legged_gym trains with 4,096; every
#: environment holds its own state arrays and recording buffers).
MAX_NUM_ENVS = 65_536
#: The longest episode time limit (s): an hour, 180,000 control steps at 50 Hz.
MAX_EPISODE_S = 3600.0
#: The most rollout threads (each holds a MuJoCo MjData).
MAX_NTHREAD = 1024


def check_sizes(num_envs: int, episode_length_s: float, nthread: int = 0) -> None:
    """One-line ``ValueError`` unless the simulator's sizes are finite and within
    ``[1, MAX_NUM_ENVS]``, ``(0, MAX_EPISODE_S]`` and ``[0, MAX_NTHREAD]`` (the checks of
    every config that sizes a simulator: msta-collect's, msta-correct's, msta-eval's)."""
    check_number("num_envs", num_envs, 1, MAX_NUM_ENVS,
                 why="every environment holds its own state and recording buffers")
    check_number("episode_length_s", episode_length_s, 0, MAX_EPISODE_S, above=True,
                 why="an hour; recordings buffer whole episodes")
    check_number("nthread", nthread, 0, MAX_NTHREAD, why="0 = one per CPU core")


@dataclass
class ControlConfig:
    """PD control and timing. A field left unset (None) takes the robot's value (its spec
    file, ``EnvConfig.robot``); a field that is set wins over every robot's:
    ``--env.control.kp=25`` simulates any robot with kp = 25. The simulator runs with
    :meth:`resolve`'s copy (``QuadrupedEnv.cfg.control`` holds the numbers in force).

    Args:
        kp: position gain of the PD actuators, > 0 (unset: the robot's; the A1's 30).
        kd: damping gain of the PD actuators, >= 0 (unset: the robot's; the A1's 0.7).
        action_scale: joint target = default pose + action_scale * action (unset: the
            robot's).
        clip_actions: actions are clipped to +-clip_actions before scaling (unset: the
            robot's).
        sim_dt: physics step (s) (unset: the robot's).
        decimation: physics steps per control step (unset: the robot's; the A1's 0.005 s x
            4 -> 50 Hz).
    """

    kp: float | None = None
    kd: float | None = None
    action_scale: float | None = None
    clip_actions: float | None = None
    sim_dt: float | None = None
    decimation: int | None = None

    def __post_init__(self) -> None:
        for name in ("kp", "kd", "action_scale", "clip_actions", "sim_dt"):
            value, bound = getattr(self, name), ">= 0" if name == "kd" else "> 0"
            # kd may be 0 (a pure P controller); EnvConfig refuses NaN and infinity
            if value is not None and not (value >= 0 if name == "kd" else value > 0):
                raise ValueError(f"control.{name}={value} must be {bound}")
        if self.decimation is not None and self.decimation < 1:
            raise ValueError(f"control.decimation={self.decimation} must be >= 1")

    def resolve(self, robot: RobotDescription) -> ControlConfig:
        """A copy whose None fields hold ``robot``'s values (the set fields kept).

        Args:
            robot: the simulated robot's description.
        """
        return replace(self, **{f.name: getattr(robot, f.name) for f in fields(self)
                                if getattr(self, f.name) is None})


@dataclass
class NoiseConfig:
    """Uniform observation noise; half-widths come from the registry, times ``scale``.

    Args:
        enabled: add the noise to every observation.
        scale: multiplies every sensor's noise half-width (the sensor registry's).
    """

    enabled: bool = True
    scale: float = 1.0


#: The largest observation-noise multiple (1e300 turned every observation into +-inf).
MAX_NOISE_SCALE = 100.0


@dataclass
class EnvConfig:
    """Args:
        robot: the simulated robot: a shipped robot's name (``msta.data.robot.robot_names``)
            or the path of a ``.toml`` spec file (docs/robots.md).
        num_envs: environments stepped together.
        seed: seeds terrain, randomization, commands, noise and spawns.
        episode_length_s: time limit (s).
        nthread: rollout threads (0 = all cores).
        spawn_offset: m, uniform xy offset of the spawn point around the tile centre.
        type_weights: share of environments per terrain type (aligned with terrain.types);
            empty = uniform.
        fall_gravity_z: a fall is declared when the projected gravity's z exceeds this
            (the trunk is tilted more than ~60 degrees), or the trunk touches the ground.
        collision: robot collision set: "fast" (feet, trunk, upper calves; default) or
            "full" (also whole calves and thighs; ~1.3x slower physics).
    """

    robot: str = "a1"
    num_envs: int = 256
    seed: int = 0
    episode_length_s: float = 20.0
    nthread: int = 2
    spawn_offset: float = 1.0
    type_weights: tuple[float, ...] = ()
    fall_gravity_z: float = -0.5
    collision: str = "fast"
    terrain: TerrainConfig = field(default_factory=TerrainConfig)
    commands: CommandConfig = field(default_factory=CommandConfig)
    randomization: RandomizationConfig = field(default_factory=RandomizationConfig)
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    rewards: RewardConfig = field(default_factory=RewardConfig)
    control: ControlConfig = field(default_factory=ControlConfig)

    def __post_init__(self) -> None:
        check_sizes(self.num_envs, self.episode_length_s, self.nthread)
        check_finite_fields(self, "env.")
        check_number("env.noise.scale", self.noise.scale, 0, MAX_NOISE_SCALE,
                     why="times each sensor's noise half-width; larger drowns every reading")
        self.type_weights = tuple(self.type_weights)
        check_collision_set(self.collision)
        self._robot = (self.robot, load_sim_robot(self.robot))
        if self.type_weights and len(self.type_weights) != len(self.terrain.types):
            raise ValueError(f"type_weights {self.type_weights} must have one weight per "
                             f"terrain type {self.terrain.types}")

    @property
    def robot_description(self) -> RobotDescription:
        """The description ``robot`` names (loaded and checked at construction; loaded again
        if ``robot`` was changed since)."""
        if self._robot[0] != self.robot:
            self._robot = (self.robot, load_sim_robot(self.robot))
        return self._robot[1]

    def resolved(self) -> EnvConfig:
        """A (shallow) copy whose ``control`` fields are all numbers: the set ones, else the
        robot's (:meth:`ControlConfig.resolve`); the config a ``QuadrupedEnv`` runs with."""
        out = copy.copy(self)
        out.control = self.control.resolve(self.robot_description)
        return out

    @property
    def teacher_robot(self) -> RobotDescription:
        """The robot's description with the control numbers in force (the set
        ``control`` fields win): what a teacher built for this simulator plans with
        (``msta.policies.teacher.config.build_teacher``)."""
        control = self.control.resolve(self.robot_description)
        return replace(self.robot_description,
                       **{f.name: getattr(control, f.name) for f in fields(control)})

    @property
    def dt(self) -> float:
        """Control period (s): ``sim_dt * decimation`` in force."""
        control = self.control.resolve(self.robot_description)
        return control.sim_dt * control.decimation

    @property
    def max_episode_steps(self) -> int:
        return int(round(self.episode_length_s / self.dt))


def load_sim_robot(name_or_path: str, option: str = "env.robot") -> RobotDescription:
    """``load_robot`` with its one-line ``ValueError`` prefixed by the option, and a check
    that the simulator's observations (sized by the sensor registry) fit the robot.

    Args:
        name_or_path: a shipped robot's name or a spec file's path.
        option: the option that named it, as messages name it (msta-eval: ``robot``).
    """
    try:
        description = load_robot(name_or_path)
    except ValueError as err:
        raise ValueError(f"{option}={name_or_path}: {err}") from None
    if (description.num_joints, len(description.feet)) != (len(JOINT_NAMES), len(LEGS)):
        raise ValueError(f"{option}={name_or_path}: the simulator's observations are sized "
                         f"for {len(JOINT_NAMES)} joints and {len(LEGS)} feet (the sensor "
                         f"registry's); {description.name} has {description.num_joints} "
                         f"joints and {len(description.feet)} feet")
    return description

"""Configuration of the batched simulator (``msta.collect.sim.env.QuadrupedEnv``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from msta.collect.sim import robot
from msta.collect.sim.commands import CommandConfig
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.rewards import RewardConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.data.checks import check_finite_fields, check_number
from msta.data.robot import ACTION_SCALE, CLIP_ACTIONS, DECIMATION, KD, KP, SIM_DT

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
    """Args:
        kp, kd: PD gains of the position actuators (paper: 30, 0.7).
        action_scale: joint target = default pose + action_scale * action.
        clip_actions: actions are clipped to +-clip_actions before scaling.
        sim_dt: physics step (s).
        decimation: physics steps per control step (0.005 s x 4 -> 50 Hz).
    """

    kp: float = KP
    kd: float = KD
    action_scale: float = ACTION_SCALE
    clip_actions: float = CLIP_ACTIONS
    sim_dt: float = SIM_DT
    decimation: int = DECIMATION

    def __post_init__(self) -> None:
        for name in ("kp", "kd", "action_scale", "clip_actions", "sim_dt"):
            if not getattr(self, name) > 0:
                raise ValueError(f"control.{name}={getattr(self, name)} must be > 0")
        if self.decimation < 1:
            raise ValueError(f"control.decimation={self.decimation} must be >= 1")


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
        robot.check_collision_set(self.collision)
        if self.type_weights and len(self.type_weights) != len(self.terrain.types):
            raise ValueError(f"type_weights {self.type_weights} must have one weight per "
                             f"terrain type {self.terrain.types}")

    @property
    def dt(self) -> float:
        return self.control.sim_dt * self.control.decimation

    @property
    def max_episode_steps(self) -> int:
        return int(round(self.episode_length_s / self.dt))

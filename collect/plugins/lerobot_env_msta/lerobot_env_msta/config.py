"""``--env.type=msta_a1``: the LeRobot env config of msta's simulator.

lerobot-eval builds the envs through :meth:`MstaA1EnvConfig.create_envs`: one task group
per terrain type (lerobot-eval prints "Aggregated Metrics for <terrain>" and an overall
line), each a batched :class:`~lerobot_env_msta.vector_env.A1VectorEnv` (all robots of a
batch in one simulator, so ``--eval.use_async_envs`` changes nothing). ``--env.robot`` names
the simulated robot (the A1 by default; docs/robots.md): its description sets the control
rate (``fps``) and which sensors there are. The features are those of an msta dataset of
that robot: ``agent_pos`` -> ``observation.state`` (the student scalars the robot offers: the
A1's 49, the Go1's 45 without foot contacts), ``environment_state`` ->
``observation.environment_state`` (the velocity command), and the 12-dim action (the
simulator's: offsets from the default pose in units of action_scale).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from lerobot.configs import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_STATE

from msta.collect.sim.terrain import LEGGED_GYM_TYPE_WEIGHTS, TERRAIN_TYPES, TerrainConfig
from msta.data import derived
from msta.data.robot import RobotDescription, load_robot
from msta.data.sensors import ACTION_DIM, SENSORS

if TYPE_CHECKING:
    from msta.collect.sim.env_config import EnvConfig as SimConfig

#: The paper's five terrain types (the default task groups).
PAPER_TERRAINS: tuple[str, ...] = tuple(LEGGED_GYM_TYPE_WEIGHTS)
#: Env observation keys (what lerobot's ``preprocess_observation`` maps) -> dataset columns.
OBS_KEYS: dict[str, str] = {"agent_pos": OBS_STATE, "environment_state": OBS_ENV_STATE}


def control_fps(robot: RobotDescription) -> int:
    """The robot's control rate (Hz): 1 / (``sim_dt`` x ``decimation``), the A1's 50.

    Args:
        robot: the simulated robot's description.
    """
    return int(round(1.0 / robot.control_dt))


def observation_features(robot: RobotDescription | None = None) -> dict[str, PolicyFeature]:
    """``agent_pos`` / ``environment_state`` features: the derived columns of a dataset that
    records every sensor the robot offers (:mod:`msta.data.derived`, the same order and
    sizes).

    Args:
        robot: the simulated robot's description (None: every registry sensor, the A1's).
    """
    columns = [s.column for s in SENSORS.values() if robot is None or s.name in robot.sensors]
    feats = derived.features(columns)
    kinds = {OBS_STATE: FeatureType.STATE, OBS_ENV_STATE: FeatureType.ENV}
    return {key: PolicyFeature(type=kinds[col], shape=tuple(feats[col]["shape"]))
            for key, col in OBS_KEYS.items()}


@EnvConfig.register_subclass("msta_a1")
@dataclass
class MstaA1EnvConfig(EnvConfig):
    """msta's quadruped in MuJoCo on legged_gym terrains (``--env.type=msta_a1``): the A1,
    or the robot ``--env.robot`` names.

    An episode succeeds when the robot is still up at the time limit (the simulator's
    ``timeout`` end); the reward is the simulator's per-step reward (``collect/sim/rewards.py``).
    A batch of episodes shares one random stream seeded by its first seed (lerobot-eval's
    ``--seed`` + the batch offset), and episode k of a batch runs on level
    ``levels[seed_k mod len(levels)]``.
    """

    task: str | None = "A1-v0"
    """a label only (lerobot logs it); the terrains are the tasks."""
    robot: str = "a1"
    """the simulated robot: a shipped robot's name (a1, go1) or the path of a robot spec file
    (docs/robots.md); its description sets the control rate and the sensors."""
    fps: int = 0
    """control rate (Hz); fixed by the robot (sim_dt x decimation of its description: the A1's
    0.005 s x 4, 50 Hz). 0: the robot's; another value than the robot's is refused."""
    terrains: tuple[str, ...] = PAPER_TERRAINS
    """terrain types, one lerobot-eval task group each (``--eval.n_episodes`` per terrain);
    known: flat, smooth_slope, rough_slope, stairs_up, stairs_down, discrete."""
    levels: tuple[int, ...] = (0, 1, 2)
    """terrain difficulty levels (0-9) the episodes cycle through."""
    platform_size: float = 0.0
    """side (m) of a flat square at each tile's centre, where robots start (within 1 m of
    the centre). 0: no platform, each robot starts on its terrain (slope, steps, blocks), so
    a robot that stays where it starts still meets it; 3.0: legged_gym's spawn platform,
    where every terrain looks flat until a robot walks off it."""
    episode_length_s: float = 20.0
    """episode time limit (s); lerobot-eval runs at most this many seconds x fps steps."""
    noise: bool = True
    """observation noise on."""
    randomization: bool = True
    """domain randomization (dynamics, pushes, latency) on."""
    heading_commands: bool = True
    """the yaw-rate command steers to a sampled heading (paper); false samples it directly."""
    video: bool = True
    """film the robots for lerobot-eval's videos (one frame per control step; only the
    terrain within 8 m of each robot is drawn, without shadows: about 0.02 s a frame with
    software OpenGL).
    false: nothing is rendered, an evaluation costs only simulation and the policy;
    lerobot-eval (0.6.1) still writes its video files, of blank 16x16 frames, unless it
    records instead (--eval.recording=true), and a warning says so."""
    video_robots: int = 10
    """robots of each terrain filmed; the others get a gray frame. lerobot-eval keeps the
    first --eval.max_episodes_rendered (10 by default) and drops the rest, so filming more
    only costs time; when you raise --eval.max_episodes_rendered, raise this to the same."""
    video_shadows: bool = False
    """draw shadows in the videos (about 4x the time of a frame with software OpenGL)."""
    video_width: int = 320
    """video frame width (pixels)."""
    video_height: int = 240
    """video frame height (pixels)."""
    nthread: int = 1
    """MuJoCo rollout threads per simulator."""
    features: dict[str, PolicyFeature] = field(default_factory=lambda: {
        ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,)),
        **observation_features()})
    """env features (the policy's, before ``features_map``): action, agent_pos,
    environment_state."""
    features_map: dict[str, str] = field(default_factory=lambda: {ACTION: ACTION, **OBS_KEYS})
    """env feature -> policy feature name."""

    def __post_init__(self) -> None:
        self.terrains, self.levels = tuple(self.terrains), tuple(int(v) for v in self.levels)
        try:
            described = load_robot(self.robot)
        except ValueError as e:
            raise ValueError(f"robot={self.robot}: {e}") from None
        rate = control_fps(described)
        self.fps = self.fps or rate
        if self.fps != rate:
            raise ValueError(f"fps={self.fps}: robot {described.name!r} runs at {rate} Hz "
                             "(fixed by its description's sim_dt x decimation)")
        self.features = {**self.features, **observation_features(described)}
        if not self.terrains:
            raise ValueError("terrains is empty; name at least one terrain type")
        for t in self.terrains:
            if t not in TERRAIN_TYPES:
                raise ValueError(f"unknown terrain {t!r}; known terrains: {list(TERRAIN_TYPES)}")
        if len(set(self.terrains)) != len(self.terrains):
            raise ValueError(f"terrains has duplicates: {list(self.terrains)}")
        num_levels = TerrainConfig().num_levels
        if not self.levels or not all(0 <= v < num_levels for v in self.levels):
            raise ValueError(f"levels {list(self.levels)} must be levels in [0, {num_levels})")
        tile = TerrainConfig().tile_size
        if not 0.0 <= self.platform_size <= tile:
            raise ValueError(f"platform_size={self.platform_size} must be in [0, {tile}] m "
                             "(a tile's side)")
        if not self.episode_length_s > 0:
            raise ValueError(f"episode_length_s={self.episode_length_s} must be > 0")
        if self.video_width < 2 or self.video_height < 2:
            raise ValueError(f"video size {self.video_width}x{self.video_height} must be >= 2x2")
        if self.video_robots < 0:
            raise ValueError(f"video_robots={self.video_robots} must be >= 0")
        if self.nthread < 1:
            raise ValueError(f"nthread={self.nthread} must be >= 1")

    @property
    def gym_kwargs(self) -> dict[str, Any]:
        """The settings :meth:`create_envs` passes to each env (no gym id is involved)."""
        return {"levels": self.levels, "video": self.video, "video_robots": self.video_robots,
                "shadows": self.video_shadows, "width": self.video_width,
                "height": self.video_height}

    def sim_config(self, terrain: str, num_envs: int) -> SimConfig:
        """The simulator config of one task group.

        Args:
            terrain: its terrain type (only that column of tiles is built, curriculum off,
                ``platform_size`` at each tile's centre).
            num_envs: robots simulated together (lerobot-eval's ``--eval.batch_size``).
        """
        # lerobot imports this plugin at the start of every command: MuJoCo waits for envs
        from msta.collect.sim.commands import CommandConfig  # lazy: MuJoCo loads when envs are made

        # lazy: MuJoCo loads when envs are made
        from msta.collect.sim.env_config import EnvConfig as SimConfig
        from msta.collect.sim.env_config import NoiseConfig  # lazy: MuJoCo loads when envs are made

        # lazy: MuJoCo loads when envs are made
        from msta.collect.sim.randomization import RandomizationConfig

        return SimConfig(
            robot=self.robot, num_envs=num_envs, episode_length_s=self.episode_length_s, nthread=self.nthread,
            terrain=TerrainConfig(types=(terrain,), curriculum=False,
                                  platform_size=self.platform_size),
            commands=CommandConfig(use_heading=self.heading_commands),
            noise=NoiseConfig(enabled=self.noise),
            randomization=RandomizationConfig(enabled=self.randomization))

    def create_envs(self, n_envs: int, use_async_envs: bool = False
                    ) -> dict[str, dict[int, Any]]:
        """``{terrain: {0: A1VectorEnv}}``, one batched simulator of ``n_envs`` robots per
        terrain.

        Args:
            n_envs: robots per simulator (lerobot-eval's ``--eval.batch_size``).
            use_async_envs: ignored: the batched simulator already steps every robot of a
                batch at once, in this process.
        """
        # lazy: lerobot imports the plugin on every command; the simulator loads when envs are made
        from lerobot_env_msta.vector_env import A1VectorEnv

        if n_envs < 1:
            raise ValueError(f"n_envs={n_envs} must be >= 1")
        return {t: {0: A1VectorEnv(self.sim_config(t, n_envs), task=t, **self.gym_kwargs)}
                for t in self.terrains}

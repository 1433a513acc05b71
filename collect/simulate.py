"""``msta-sim``: roll a teacher in the batched simulator, print a per-terrain table, save pictures.

    msta-sim --teacher.type=zero --seconds=5 --env.num_envs=64 --output_dir=outputs/sim
    msta-sim --teacher.type=gait --env.terrain.types='[flat,stairs_up]'
    msta-sim --robot=specs/my_robot.toml --teacher.type=zero

The teacher is chosen as everywhere else (``--teacher.type``, ``--teacher.path``: the same
:class:`~msta.policies.teacher.config.TeacherConfig` as msta-collect, msta-correct and msta-eval);
``zero`` holds the default pose. ``--robot`` names the robot the simulator builds (a shipped
robot or a spec file, docs/robots.md; ``--env.robot`` is read as ``--robot``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

from msta.collect.rollout import film, run
from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.render import save_strip, save_video
from msta.data.cli import parse_config
from msta.data.robot import LEGACY_ROBOT
from msta.policies.teacher.config import TeacherConfig, build_teacher


@dataclass
class SimRunConfig:
    """Args:
        robot: the simulated robot: a shipped robot's name (``a1``) or the path of a
            ``.toml`` spec file (docs/robots.md); sets ``env.robot`` (left at ``a1`` while
            ``env.robot`` names another robot: that one). The control fields
            left unset (``--env.control.*``) take this robot's values.
        env: simulator configuration.
        teacher: the teacher that drives (``--teacher.type=gait``; ``zero`` holds the
            default pose).
        seconds: simulated time per environment.
        output_dir: folder for the image strip (and video with ``video=True``).
        image: save an image strip of environment 0.
        video: also save an MP4 of environment 0.
        progress: show a progress bar.
    """

    robot: str = LEGACY_ROBOT
    env: EnvConfig = field(default_factory=lambda: EnvConfig(num_envs=64))
    teacher: TeacherConfig = field(default_factory=TeacherConfig)
    seconds: float = 5.0
    output_dir: str = "outputs/sim"
    image: bool = True
    video: bool = False
    progress: bool = True

    def __post_init__(self) -> None:
        if self.robot == LEGACY_ROBOT:  # env alone may name it (the Python API): env's wins
            self.robot = self.env.robot
        elif self.env.robot != self.robot:  # EnvConfig loads and checks the robot (one line)
            self.env = replace(self.env, robot=self.robot)
        self.teacher = self.teacher.on_robot(self.robot, "msta-sim")


def simulate(cfg: SimRunConfig) -> str:
    """Run, print and return the Markdown summary table."""
    env = QuadrupedEnv(cfg.env)
    env.reset()
    policy = build_teacher(cfg.teacher, cfg.env.teacher_robot)
    steps = max(1, int(round(cfg.seconds / env.dt)))
    summary = run(env, policy, steps, progress=cfg.progress)
    table = summary.table()
    print(f"\nrobot={env.robot.name}  teacher={cfg.teacher.type}  envs={env.num_envs}  {cfg.seconds:.1f} s each "
          f"({steps * env.num_envs:,} env steps); episode ends by reason "
          f"{dict(zip(('running', 'fall', 'timeout', 'nan'), env.resets_by_reason.tolist()))}")
    print(table)
    if cfg.image or cfg.video:
        env.reset()
        frames = film(env, policy, min(steps, 150), every=5)
        out = Path(cfg.output_dir)
        if cfg.image:
            print(f"image strip: {save_strip(frames, out / f'{cfg.teacher.type}_strip.png')}")
        if cfg.video:
            print(f"video: {save_video(frames, out / f'{cfg.teacher.type}.mp4')}")
    return table


def main(argv: list[str] | None = None) -> None:
    """Console entry point (``msta-sim``)."""
    simulate(parse_config(SimRunConfig, argv, "msta-sim", aliases={"env.robot": "robot"}))


if __name__ == "__main__":
    main()

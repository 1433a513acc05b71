"""The teacher report: episodes per tile through the shared rollout loop and metrics."""

from __future__ import annotations

import numpy as np
import pytest

from msta.collect.rollout import rollout, step_quantities
from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.eval import teacher_report as tr
from msta.policies.teacher.config import SHIPPED_RMA, TeacherConfig, build_teacher


def tiny(**kw) -> tr.TeacherReportConfig:
    base = {"teacher": TeacherConfig(type="zero"), "episodes": 3, "envs_per_tile": 2,
            "terrains": "flat", "levels": "0,3", "episode_length_s": 0.3, "nthread": 1,
            "columns": 1, "progress": False}
    base.update(kw)
    return tr.TeacherReportConfig(**base)


def test_every_tile_counts_its_episodes_and_figures():
    cfg = tiny()
    stats = tr.evaluate(cfg)
    assert set(stats) == {("flat", 0), ("flat", 3)}
    for row in stats.values():
        assert row["episodes"] == 4        # 2 envs x ceil(3 / 2) episodes, none cut short
        assert row["survival"] == 1.0      # standing still for 0.3 s does not fall
        assert row["lin_err"] > 0 and row["ang_err"] >= 0
        assert 0 < row["lin_reward"] <= tr.env_scale("lin")
    md = tr.render_markdown(stats, cfg, "cmd", 1.0, None)
    assert "| 3 | 4 | 100.0% |" in md and tr.highest_level(stats, "flat", cfg.level_list) == 3


def test_errors_are_the_per_step_means_of_the_shared_quantities():
    """One episode per environment: the tile's |v err| is the mean of step_quantities'
    vel_err over every step of its environments (the same figure msta-eval sums)."""
    cfg = tiny(episodes=1, envs_per_tile=1, levels="2")
    row = tr.evaluate(cfg)[("flat", 2)]
    env = QuadrupedEnv(EnvConfig(num_envs=1, seed=cfg.seed, episode_length_s=cfg.episode_length_s,
                                 nthread=1, terrain=TerrainConfig(types=("flat",),
                                                                  columns_per_type=1,
                                                                  curriculum=False)))
    env.reset(type_idx=np.zeros(1, dtype=np.int64), level=np.array([2]))
    errs = []
    rollout(env, build_teacher(TeacherConfig(type="zero")),
            lambda s: errs.append(step_quantities(s)["vel_err"][0]) or bool(s.res.done[0]))
    assert row["lin_err"] == pytest.approx(np.mean(errs), rel=1e-12)


def test_the_command_line_writes_the_report_with_its_regenerate_line(tmp_path, capsys):
    out = tmp_path / "q.md"
    argv = ["--teacher.type=zero", "--episodes=2", "--envs_per_tile=5", "--terrains=flat",
            "--levels=0-1", "--episode_length_s=0.1", "--nthread=1", "--columns=1",
            f"--report={out}", "--image=", "--progress=false"]
    tr.main(argv)
    md = out.read_text()
    # the options as parsed (envs_per_tile capped at episodes), progress left out
    assert (f"Regenerate: `python -m msta.eval.teacher_report --teacher.type=zero --episodes=2 "
            f"--envs_per_tile=2 --terrains=flat --levels=0-1 --episode_length_s=0.1 "
            f"--nthread=1 --columns=1 --report={out} --image=''`") in md
    assert "| 1 | 2 | 100.0% |" in md and f"wrote {out}" in capsys.readouterr().out
    assert "| survival L0-1 | mean abs(v err) L0-1 |" in md  # the levels it averaged
    gait = tr.TeacherReportConfig(teacher=TeacherConfig(type="gait"))
    assert tr.command_line(gait) == (
        "python -m msta.eval.teacher_report --teacher.type=gait --episodes=100 --envs_per_tile=10")
    # the default teacher (the shipped PPO one): --teacher.type=rma alone loads it
    assert tr.command_line(tr.TeacherReportConfig()) == (
        "python -m msta.eval.teacher_report --teacher.type=rma --episodes=100 --envs_per_tile=10")
    dart = tr.TeacherReportConfig(teacher=TeacherConfig(type="rma", path=str(SHIPPED_RMA)))
    assert f"--teacher.path={SHIPPED_RMA} " in tr.command_line(dart)


@pytest.mark.parametrize("arg, message", [
    ("--levels=3-12", "levels '3-12': give levels in [0, 9]"),
    ("--levels=a,b", "write a range (0-9) or a list (0,1,2)"),
    ("--terrains=flat,lava", "unknown terrain 'lava'"),
    ("--episodes=0", "episodes=0 must be >= 1"),
    ("--teacher.type=imported", "teacher type 'imported' needs --teacher.path"),
    ("--no-progress", "did you mean --progress?"),
])
def test_clear_errors(arg, message, capsys):
    with pytest.raises(SystemExit) as e:
        tr.main([arg])
    err = capsys.readouterr().err
    assert e.value.code == 2 and message in err and len(err.strip().splitlines()) == 1, err


def test_the_stairs_strip_is_a_film_of_the_rollout_loop(tmp_path):
    """render_stairs films through msta.collect.rollout.film: ``frames`` pictures side by side,
    one every ``steps // frames`` steps."""
    import os

    os.environ.setdefault("MUJOCO_GL", "egl")
    import matplotlib.image

    path = tr.render_stairs(tmp_path / "stairs.png", TeacherConfig(type="zero"), seconds=0.2,
                            frames=3)
    strip = matplotlib.image.imread(path)
    assert strip.shape[:2] == (360, 3 * 480) and strip.std() > 0.02


def test_robot_simulates_that_robot_and_builds_the_teacher_for_it():
    """--robot=go1: the tile's figures are those of the gait teacher built for the Go1 on the
    Go1 (the same rollout by hand); the report and its Regenerate line name the robot."""
    cfg = tiny(robot="go1", teacher=TeacherConfig(type="gait"), episodes=1, envs_per_tile=1,
               levels="0")
    row = tr.evaluate(cfg)[("flat", 0)]
    env = QuadrupedEnv(EnvConfig(robot="go1", num_envs=1, seed=cfg.seed, nthread=1,
                                 episode_length_s=cfg.episode_length_s,
                                 terrain=TerrainConfig(types=("flat",), columns_per_type=1,
                                                       curriculum=False)))
    env.reset(type_idx=np.zeros(1, dtype=np.int64), level=np.array([0]))
    teacher = build_teacher(TeacherConfig(type="gait"), env.cfg.teacher_robot)
    assert teacher.robot.name == "go1"
    errs = []
    rollout(env, teacher,
            lambda s: errs.append(step_quantities(s)["vel_err"][0]) or bool(s.res.done[0]))
    assert row["lin_err"] == pytest.approx(np.mean(errs), rel=1e-12)
    assert tr.command_line(cfg).startswith(
        "python -m msta.eval.teacher_report --teacher.type=gait --robot=go1 ")
    md = tr.render_markdown({("flat", 0): row}, cfg, tr.command_line(cfg), 1.0, None)
    assert md.startswith("# Teacher quality: `gait` on `go1`")
    assert "--robot" not in tr.command_line(tiny())  # the A1: the line as before
    with pytest.raises(ValueError, match="robot=b2: unknown robot 'b2'"):
        tiny(robot="b2")

"""A student records the robot of the dataset it was trained on; msta-correct refuses a
dataset, checkpoint and ``--env.robot`` that do not agree, and evaluates each round on the
rounds' robot (docs/robots.md)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from msta_test_helpers import random_episode, write_robot_spec  # registered by conftest.py

from msta.collect.sim.env_config import EnvConfig
from msta.data import sensors
from msta.data.features import load_info
from msta.data.msta_json import dataset_robot
from msta.data.stats import load_stats
from msta.data.writer import DatasetWriter
from msta.policies.checkpoint import PolicyPath
from msta.policies.factory import load_config, load_policy, make_policy
from msta.policies.msta import MSTAConfig
from msta.policies.teacher.config import TeacherConfig
from msta.train.cli import parse_cli
from msta.train.correct_config import CorrectConfig, RoundEvalConfig
from msta.train.offline import main as train_main
from msta.train.round_eval import RoundEvaluator
from msta.train.stage1 import dataset_inputs, train
from msta.train.stage2 import correct
from msta.train.train_config import TrainConfig


def dataset_of(root: Path, robot: str, episodes: int = 4, length: int = 20,
               recorded: tuple[str, ...] | None = None) -> Path:
    """A small dataset of random episodes that records ``robot`` (and the sensors
    ``recorded``; None: the default ones)."""
    rng = np.random.default_rng(0)
    with DatasetWriter.create(root, f"local/{robot}", robot=robot, sensors=recorded) as w:
        for i in range(episodes):
            w.add_episode(random_episode(length, rng, recorded), {
                "terrain": "flat", "terrain_level": 0, "source": "teacher", "round": 0,
                "policy": "synthetic", "policy_revision": "", "seed": i})
    return root


def student(root: Path, out: Path, robots: tuple[str, ...] = ("a1",)) -> Path:
    """An untrained tiny MSTA checkpoint with ``root``'s statistics, trained on ``robots``."""
    cfg = MSTAConfig.from_preset("tiny", history=3, robots=robots)
    return make_policy(cfg, load_stats(root)).save_pretrained(out)


def correct_cfg(dataset: Path, ckpt: Path, out: Path, robot: str = "a1",
                **kw) -> CorrectConfig:
    return CorrectConfig(policy=PolicyPath(str(ckpt)), dataset=str(dataset),
                         output_dir=str(out), env=EnvConfig(robot=robot, nthread=1),
                         teacher=TeacherConfig(type="zero"), steps=1, progress=False,
                         device="cpu", eval=kw.pop("eval", RoundEvalConfig(enabled=False)),
                         **kw)


def one_line_naming(err: pytest.ExceptionInfo, *words: str) -> None:
    msg = str(err.value)
    assert "\n" not in msg, msg
    assert all(w in msg for w in words), (words, msg)


def test_a_trained_student_records_its_datasets_robot(tmp_path):
    root = dataset_of(tmp_path / "ds", "other")
    cfg = parse_cli(TrainConfig, [f"--dataset={root}", f"--output_dir={tmp_path / 'run'}",
                                  "--policy.preset=tiny", "--policy.history=3", "--steps=2",
                                  "--batch_size=8", "--warmup_steps=1", "--progress=false",
                                  "--device=cpu", "--val_fraction=0"], prog="msta-train")
    final = train(cfg)
    assert json.loads((final / "config.json").read_text())["robots"] == ["other"]
    assert load_config(final).robots == ("other",)
    last = tmp_path / "run" / "checkpoints" / "last" / "pretrained_model"
    assert load_config(last).robots == ("other",)  # the resumable checkpoints too


def train_args(root: Path, out: Path, *extra: str) -> list[str]:
    return [f"--dataset={root}", f"--output_dir={out}", "--policy.preset=tiny",
            "--policy.history=3", "--steps=2", "--batch_size=8", "--warmup_steps=1",
            "--progress=false", "--device=cpu", "--val_fraction=0", *extra]


#: What a Go1 dataset records by default: no foot_contact.
GO1_RECORDED = tuple(n for n in sensors.DEFAULT_RECORDED if n != "foot_contact")


def test_default_inputs_a_dataset_lacks_are_left_out_with_one_line(tmp_path, capsys):
    root = dataset_of(tmp_path / "ds", "go1", recorded=GO1_RECORDED)
    train_main(train_args(root, tmp_path / "run"))
    said = [ln for ln in capsys.readouterr().out.splitlines() if "foot_contact" in ln]
    assert len(said) == 1 and "does not record foot_contact" in said[0], said
    expected = tuple(n for n in sensors.STUDENT_SENSORS if n != "foot_contact")
    final = tmp_path / "run" / "final"
    assert load_config(final).input_sensors == expected
    assert load_policy(final).processor.input_sensors == expected
    saved = json.loads((tmp_path / "run" / "train_config.json").read_text())
    assert tuple(saved["policy"]["input_sensors"]) == expected  # what --resume compares
    train_main(train_args(root, tmp_path / "run", "--steps=3", "--resume=true"))  # resumes
    assert load_config(final).input_sensors == expected


def test_inputs_named_that_the_dataset_lacks_are_a_one_line_error(tmp_path):
    root = dataset_of(tmp_path / "ds", "go1", recorded=GO1_RECORDED)
    named = ",".join(sensors.STUDENT_SENSORS)  # the defaults, named: each must be recorded
    for inputs in (f"[{named}]", "[joint_pos,foot_contact]"):
        with pytest.raises(SystemExit) as err:
            train_main(train_args(root, tmp_path / "run", f"--policy.input_sensors={inputs}"))
        msg = str(err.value)
        assert "\n" not in msg and "does not record foot_contact" in msg, msg
        assert not (tmp_path / "run" / "final").exists()


def test_an_a1_dataset_trains_the_same_student_as_before(tmp_path):
    root = dataset_of(tmp_path / "ds", "a1")
    cfg = parse_cli(TrainConfig, train_args(root, tmp_path / "run"), prog="msta-train")
    assert dataset_inputs(cfg.policy, root) is cfg.policy
    train(cfg)
    assert load_config(tmp_path / "run" / "final").input_sensors == sensors.STUDENT_SENSORS


def test_correct_refuses_a_dataset_of_another_robot(tmp_path):
    root = dataset_of(tmp_path / "ds", "a1")
    spec = write_robot_spec(tmp_path)  # the A1's spec named "other"
    cfg = correct_cfg(root, student(root, tmp_path / "ckpt"), tmp_path / "out", str(spec))
    with pytest.raises(ValueError) as err:
        correct(cfg)
    one_line_naming(err, "'a1'", "'other'", "--env.robot", "--dataset")
    assert not (tmp_path / "out").exists()  # refused before anything is written


def test_correct_refuses_a_checkpoint_trained_on_another_robot(tmp_path):
    spec = write_robot_spec(tmp_path)
    root = dataset_of(tmp_path / "ds", "other")
    ckpt = student(root, tmp_path / "ckpt")  # trained on the A1
    with pytest.raises(ValueError) as err:
        correct(correct_cfg(root, ckpt, tmp_path / "out", str(spec)))
    one_line_naming(err, "'a1'", "'other'", "--env.robot", "--policy.path")
    assert not (tmp_path / "out").exists()


def test_correct_refuses_a_checkpoint_of_several_robots(tmp_path):
    """Its rounds would retrain it on one robot's episodes alone (msta-train --more_datasets
    trains one of both)."""
    root = dataset_of(tmp_path / "ds", "a1")
    ckpt = student(root, tmp_path / "ckpt", robots=("a1", "go1"))
    with pytest.raises(ValueError) as err:
        correct(correct_cfg(root, ckpt, tmp_path / "out"))
    one_line_naming(err, "robots a1, go1", "a1's episodes alone", "--more_datasets")
    assert not (tmp_path / "out").exists()


def test_correct_refuses_a_per_round_evaluation_on_another_robot(tmp_path):
    root = dataset_of(tmp_path / "ds", "a1")
    spec = write_robot_spec(tmp_path)
    with pytest.raises(ValueError) as err:
        correct_cfg(root, tmp_path / "ckpt", tmp_path / "out",
                    eval=RoundEvalConfig(robot=str(spec)))
    one_line_naming(err, "'a1'", "'other'", "eval.robot")


def test_the_per_round_evaluation_simulates_the_rounds_robot(tmp_path):
    spec = write_robot_spec(tmp_path)
    trials = RoundEvalConfig(trials=1, episode_length_s=0.1, terrains="flat", levels="0",
                             num_envs=1, nthread=1)
    ev = RoundEvaluator(trials, TeacherConfig(type="zero"), robot=str(spec))
    assert ev.teacher()["config"]["robot"] == "other"
    assert ev.ev.env.robot.name == "other"


def test_a_student_of_matching_robots_is_accepted(tmp_path):
    """Dataset, checkpoint and --env.robot all name "other": the inputs pass the checks and
    the round's episodes are appended (the run is stopped there by the phase hook)."""
    spec = write_robot_spec(tmp_path)
    root = dataset_of(tmp_path / "ds", "other")
    ckpt = student(root, tmp_path / "ckpt", robots=("other",))
    cfg = correct_cfg(root, ckpt, tmp_path / "out", str(spec), rounds=1, episodes_per_round=2,
                      num_envs=2, episode_length_s=0.1, keep_unfinished=False)

    def stop(phase: str, r: int) -> None:
        if phase == "committed":
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        correct(cfg, on_phase=stop)
    assert load_info(root)["total_episodes"] == 4 + 2
    assert dataset_robot(root) == "other"

"""Every command that chooses a teacher defaults to the best shipped one, the PPO-trained RMA
teacher (``SHIPPED_RMA_PPO``), and says so in ``--help``; ``--teacher.type=gait`` still
selects the gait controller and ``--teacher.type=rma`` alone the default, rma_ppo (the DART
warm start takes its path)."""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from typing import Any

import pytest
from msta_test_helpers import write_robot_spec  # registered by tests/conftest.py

from msta.data import cli
from msta.data.robot import load_robot
from msta.policies.teacher.config import (
    SHIPPED_RMA,
    SHIPPED_RMA_PPO,
    SHIPPED_ROBOT_RMA,
    TeacherConfig,
)


def _collect(argv: Sequence[str]) -> Any:
    from msta.collect.record import parse_config
    return parse_config(argv)


def _correct(argv: Sequence[str]) -> Any:
    from msta.train.online import parse_args
    return parse_args(argv)


def _finetune(argv: Sequence[str]) -> Any:
    from msta.train.finetune import parse_args
    return parse_args(argv)


def _with(module: str, name: str, prog: str, *required: str) -> Callable[[Sequence[str]], Any]:
    """The command's own parse: ``msta.data.cli.parse_config`` on its config class, as its
    ``main`` calls it (``required``: the options the command cannot run without)."""
    def parse(argv: Sequence[str]) -> Any:
        import importlib
        return cli.parse_config(getattr(importlib.import_module(module), name),
                                [*required, *argv], prog)
    return parse


#: every command with ``--teacher.*`` options (``grep -rn "teacher: TeacherConfig"``)
COMMANDS = {
    "msta-collect": _collect,
    "msta-correct": _correct,
    "msta-finetune": _finetune,
    "msta-sim": _with("msta.collect.simulate", "SimRunConfig", "msta-sim"),
    "msta-eval": _with("msta.eval.evaluate", "EvalConfig", "msta-eval"),
    "msta-compare": _with("msta.eval.apps.compare", "CompareConfig", "msta-compare",
                          "--collect_episodes=2"),
    "msta-repro": _with("msta.eval.apps.repro", "ReproConfig", "msta-repro"),
    "demo": _with("msta.eval.apps.demo", "DemoConfig", "python -m msta.eval.apps.demo"),
    "label_check": _with("msta.eval.label_check", "LabelCheckConfig", "label_check"),
    "teacher_report": _with("msta.eval.teacher_report", "TeacherReportConfig", "teacher_report"),
}


def test_the_config_default_is_the_shipped_ppo_teacher():
    assert TeacherConfig() == TeacherConfig(type="rma", path=str(SHIPPED_RMA_PPO))
    assert TeacherConfig().label == "rma (rma_ppo)"
    assert TeacherConfig(type="gait") == TeacherConfig(type="gait", path="")
    assert TeacherConfig(type="rma") == TeacherConfig()  # rma alone: the default, rma_ppo
    assert TeacherConfig(type="rma", path=str(SHIPPED_RMA)).path == str(SHIPPED_RMA)


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_each_command_defaults_to_the_shipped_ppo_teacher(command):
    parse = COMMANDS[command]
    assert parse([]).teacher == TeacherConfig(type="rma", path=str(SHIPPED_RMA_PPO))
    assert parse(["--teacher.type=gait"]).teacher == TeacherConfig(type="gait", path="")
    assert parse(["--teacher.type=rma"]).teacher == TeacherConfig(type="rma",
                                                                  path=str(SHIPPED_RMA_PPO))


#: the commands above that simulate a robot other than the A1, with the option naming it
ROBOT_OPTION = {"msta-collect": "--env.robot", "msta-correct": "--env.robot", "msta-sim": "--robot",
                "msta-eval": "--robot", "demo": "--robot", "label_check": "--robot",
                "teacher_report": "--robot"}


@pytest.mark.parametrize("command", sorted(ROBOT_OPTION))
def test_on_the_go1_each_command_takes_its_shipped_teacher(command, capsys):
    """The A1's shipped checkpoints read joint angles about the A1's pose: on the Go1 the
    default teacher (or either of them named) becomes the Go1's, said in one line; another
    teacher is kept."""
    go1 = TeacherConfig(type="rma", path=str(SHIPPED_ROBOT_RMA["go1"]))
    option = ROBOT_OPTION[command]
    for named in ([], [f"--teacher.path={SHIPPED_RMA}"]):
        assert COMMANDS[command]([f"{option}=go1", *named]).teacher == go1
        assert "robot go1 takes its shipped teacher rma (go1_ppo)" in capsys.readouterr().out
    assert COMMANDS[command]([f"{option}=go1", "--teacher.type=gait"]).teacher == TeacherConfig(
        type="gait")
    assert COMMANDS[command]([option + "=a1"]).teacher == TeacherConfig()
    assert "takes its shipped teacher" not in capsys.readouterr().out


@pytest.mark.parametrize("command", sorted(ROBOT_OPTION))
def test_the_a1s_teacher_on_a_robot_msta_ships_none_for_is_refused(command, tmp_path, capsys):
    spec = write_robot_spec(tmp_path, "longlegs", base=load_robot("go1"))
    with pytest.raises(SystemExit):
        COMMANDS[command]([f"{ROBOT_OPTION[command]}={spec}"])
    err = capsys.readouterr().err
    assert f"{ROBOT_OPTION[command]}={spec}: the teacher {SHIPPED_RMA_PPO} was trained on the A1" \
        in err and "--teacher.type=gait" in err


def _option_help(help_text: str, flag: str) -> str:
    """The help of ``flag``, its continuation lines joined."""
    m = re.search(rf"^  {re.escape(flag)} \S+(.*?)(?=^  -|^\S|\Z)", help_text,
                  re.MULTILINE | re.DOTALL)
    assert m, f"{flag} not in the help"
    return " ".join(m.group(1).split())


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_help_states_the_default_teacher(command, capsys):
    with pytest.raises(SystemExit) as e:
        COMMANDS[command](["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert _option_help(out, "--teacher.type").endswith("(default: rma)")
    # the help wraps a long path anywhere (after a '-' of the checkout's folder name too):
    # compare without the whitespace the wrapping inserts
    path_help = "".join(_option_help(out, "--teacher.path").split())
    assert path_help.endswith("".join(f"(default: {SHIPPED_RMA_PPO})".split()))

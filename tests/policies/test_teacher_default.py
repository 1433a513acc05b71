"""Every command that chooses a teacher defaults to the best shipped one, the PPO-trained RMA
teacher (``SHIPPED_RMA_PPO``), and says so in ``--help``; ``--teacher.type=gait`` still
selects the gait controller and ``--teacher.type=rma`` alone the default, rma_ppo (the DART
warm start takes its path)."""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from typing import Any

import pytest

from msta.data import cli
from msta.policies.teacher.config import SHIPPED_RMA, SHIPPED_RMA_PPO, TeacherConfig


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

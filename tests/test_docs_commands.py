"""Every command line written in README.md and docs/ parses as written.

Each ``msta-*`` / ``python -m <tool>`` command of a code block or inline code span is split
like a shell would (continuation lines joined) and given to that command's own parser,
without running it: a renamed or removed option in the code fails here, naming the file and
the line. Commands with placeholders (``<checkpoint>``, ``...``) are checked for their
option names only.
"""

from __future__ import annotations

import re
import shlex
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from msta.collect.record import parse_config as collect_args
from msta.collect.simulate import SimRunConfig
from msta.data.cli import parse_config
from msta.data.hub_cli import parse_command
from msta.eval.apps.compare import CompareConfig
from msta.eval.apps.demo import DemoConfig
from msta.eval.bench.data import BenchDataConfig
from msta.eval.bench.deploy import BenchDeployConfig
from msta.eval.bench.learn import BenchLearnConfig
from msta.eval.bench.sim import BenchSimConfig
from msta.eval.bench.train import BenchTrainConfig
from msta.eval.eval_config import EvalConfig
from msta.eval.label_check import LabelCheckConfig
from msta.eval.report import EvalReportConfig
from msta.eval.teacher_report import TeacherReportConfig
from msta.policies.export_cli import ExportConfig
from msta.train.cli import parse_cli
from msta.train.guard_fit import GuardCommand
from msta.train.online import parse_args as correct_args
from msta.train.teacher.config import TrainTeacherConfig
from msta.train.train_config import TrainConfig

REPO = Path(__file__).resolve().parents[1]


def _config(cls: type, prog: str) -> Callable[[list[str]], Any]:
    return lambda argv: parse_config(cls, argv, prog)


#: command (as written in the docs, after an optional ``.venv/bin/``) -> its parser
PARSERS: dict[str, Callable[[list[str]], Any]] = {
    "msta-collect": lambda argv: collect_args(argv),
    "msta-train": lambda argv: parse_cli(TrainConfig, argv, "msta-train"),
    "msta-correct": correct_args,
    "msta-train-teacher": lambda argv: parse_config(TrainTeacherConfig, argv, "msta-train-teacher",
                                                    aliases={"env.seed": "seed"}),
    "msta-eval": _config(EvalConfig, "msta-eval"),
    "msta-compare": _config(CompareConfig, "msta-compare"),
    "msta-sim": _config(SimRunConfig, "msta-sim"),
    "msta-hub": parse_command,
    "msta-demo": _config(DemoConfig, "msta-demo"),
    "python -m msta.eval.apps.demo": _config(DemoConfig, "python -m msta.eval.apps.demo"),
    "python -m msta.eval.bench.learn": _config(BenchLearnConfig, "python -m msta.eval.bench.learn"),
    "python -m msta.eval.bench.train": _config(BenchTrainConfig, "python -m msta.eval.bench.train"),
    "python -m msta.eval.bench.sim": _config(BenchSimConfig, "python -m msta.eval.bench.sim"),
    "python -m msta.eval.bench.data": _config(BenchDataConfig, "python -m msta.eval.bench.data"),
    "python -m msta.eval.bench.deploy": _config(BenchDeployConfig, "python -m msta.eval.bench.deploy"),
    "msta-export": _config(ExportConfig, "msta-export"),
    "msta-guard": lambda argv: parse_config(GuardCommand, argv, "msta-guard",
                                            positionals=("command",)),
    "python -m msta.eval.label_check": _config(LabelCheckConfig, "python -m msta.eval.label_check"),
    "python -m msta.eval.teacher_report": _config(TeacherReportConfig,
                                             "python -m msta.eval.teacher_report"),
    "python -m msta.eval.report": lambda argv: parse_config(
        EvalReportConfig, argv, "python -m msta.eval.report", positionals=("metrics",)),
}
#: A parse that fails only because an example input does not exist here.
MISSING_INPUT = re.compile(r"no such (file|checkpoint)|does not exist")
_START = re.compile(r"(?:^|[\s`(])(?:\.venv/bin/)?(msta-[a-z]+(?:-[a-z]+)*|python -m [\w.]+)(?=[\s`]|$)")


def documented_commands(root: Path = REPO) -> list[tuple[str, str, str]]:
    """(where, command, argument text) for every command line in README.md and docs/."""
    found = []
    for path in [root / "README.md", *sorted((root / "docs").rglob("*.md"))]:
        lines = path.read_text().splitlines()
        in_block = False
        i = 0
        while i < len(lines):
            line = lines[i]
            if line.lstrip().startswith("```"):
                in_block = not in_block
                i += 1
                continue
            where = f"{path.relative_to(root)}:{i + 1}"
            if in_block:
                text = line
                while text.rstrip().endswith("\\") and i + 1 < len(lines):
                    i += 1
                    text = text.rstrip()[:-1] + " " + lines[i]
                for m in _START.finditer(text):
                    if m.group(1) in PARSERS:
                        found.append((where, m.group(1), _args_text(text[m.end():])))
            else:
                for span in re.findall(r"`([^`]+)`", line):
                    m = _START.match(span)
                    if m and m.group(1) in PARSERS:
                        found.append((where, m.group(1), _args_text(span[m.end():])))
            i += 1
    return found


def _args_text(rest: str) -> str:
    """The command's own arguments: up to a comment, a pipe or a chained command."""
    return re.split(r"\s#|\s\||&&|;|`", rest)[0].strip()


def _options_only(argv: list[str]) -> list[str]:
    """For a command with placeholders: its option names with a neutral value dropped."""
    return [a.split("=", 1)[0] + "=" for a in argv if a.startswith("--")]


COMMANDS = documented_commands()


def test_the_docs_show_commands(tmp_path, capsys):
    """The extraction works: the README's pipeline is found; in a planted doc, a continued
    block line and an inline span are read whole, and a renamed option fails to parse."""
    names = {c for _, c, _ in COMMANDS}
    assert {"msta-collect", "msta-train", "msta-correct", "msta-eval", "msta-hub"} <= names
    assert len(COMMANDS) > 20
    (tmp_path / "docs").mkdir()
    (tmp_path / "README.md").write_text(
        "```bash\n.venv/bin/msta-train --steps=3 \\\n    --threads=2   # old name\n```\n"
        "Run `msta-eval --trials=4 --output_dir=x` or read about `msta-compare`.\n")
    found = documented_commands(tmp_path)
    assert found == [("README.md:2", "msta-train", "--steps=3      --threads=2"),
                     ("README.md:5", "msta-eval", "--trials=4 --output_dir=x"),
                     ("README.md:5", "msta-compare", "")]
    with pytest.raises(SystemExit):
        PARSERS["msta-train"](shlex.split(found[0][2]))
    assert "did you mean --num_threads" in capsys.readouterr().err


def is_mention(command: str, argv: list[str]) -> bool:
    """A command named in prose (`msta-compare`, `msta-hub push-dataset`), not run."""
    return not argv or command == "msta-hub" and len(argv) == 1 and not argv[0].startswith("-")


@pytest.mark.parametrize(("where", "command", "args"), COMMANDS,
                         ids=[f"{w} {c}" for w, c, _ in COMMANDS])
def test_documented_command_parses(where, command, args, capsys):
    argv = shlex.split(args)
    if is_mention(command, argv) or "--help" in argv:
        return
    if any(p in args for p in ("<", "...", "*")) or "[" in args and "=[" not in args:
        known = parse_help_options(command, capsys)
        unknown = [a for a in _options_only(argv) if a.rstrip("=").split(".")[0] not in known]
        assert not unknown, f"{where}: {command} has no option {unknown}"
        return
    try:
        PARSERS[command](argv)
    except SystemExit as e:
        err = capsys.readouterr().err.strip()
        if not MISSING_INPUT.search(err):  # an example path that earlier steps create is fine
            pytest.fail(f"{where}: `{command} {args}` does not parse (exit {e.code}): {err}")


def parse_help_options(command: str, capsys) -> set[str]:
    """Top-level option names (``--policy`` for ``--policy.path``) from ``--help``."""
    argv = ["push", "--help"] if command == "msta-hub" else ["--help"]
    with pytest.raises(SystemExit):
        PARSERS[command](argv)
    text = capsys.readouterr().out
    return {m.split(".")[0] for m in re.findall(r"^\s+(--[\w.]+)", text, re.MULTILINE)}

"""Every option of every msta command, fuzzed: hostile values (NaN, infinities, negative, zero,
huge, empty, the wrong type, a folder, a FIFO, /dev/null, YAML specials) end in a one-line
error (exit 2) or are accepted, never a traceback, a hang or a crash.

The commands come from pyproject.toml's console scripts (msta-hub's from its command table)
plus the ``python -m`` tools, and their options from their own ``--help``, which is built
from their configs: a new command or option is fuzzed without an edit here.

What runs is each command's parsing and its config's checks (``__post_init__``): the fuzz
stops a command right after its config is built (draccus' ``parse_args`` returns), so an
accepted value starts no simulation, training or server. Options that are checked later, when
the command runs, have their own tests beside the command.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import os
import re
import signal
import tomllib
from pathlib import Path

import draccus
import pytest

from msta.data.hub_cli import COMMANDS as HUB_COMMANDS
from msta.data.hub_cli import main as hub_main

ROOT = Path(__file__).resolve().parents[1]
#: ``python -m`` tools that parse a config of their own (the console scripts come from
#: pyproject.toml).
MODULES = ["msta.eval.bench.learn", "msta.eval.bench.train", "msta.eval.bench.sim",
           "msta.eval.bench.data", "msta.eval.bench.deploy", "msta.eval.bench.threads",
           "msta.eval.label_check", "msta.eval.report", "msta.eval.teacher_report"]
#: What no number option may accept (docs/security.md: NaN never passes).
NEVER = ("nan", "inf", "-inf", "9" * 23, "[nan]")
#: Seconds one command may take to answer a value (parsing and checks only).
LIMIT_S = 20


def _commands() -> dict[str, object]:
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    out: dict[str, object] = {}
    for name, target in sorted(scripts.items()):
        module, func = target.split(":")
        if name == "msta-hub":
            for sub in HUB_COMMANDS:
                out[f"msta-hub {sub}"] = lambda argv, sub=sub: hub_main([sub, *argv])
            continue
        out[name] = getattr(importlib.import_module(module), func)
    for module in MODULES:
        out[f"python -m {module}"] = importlib.import_module(module).main
    return out


COMMANDS = _commands()


class _Parsed(Exception):
    """Raised where the command's config is built: the value was accepted."""


@pytest.fixture(autouse=True)
def stop_after_parsing(monkeypatch):
    real = draccus.argparsing.ArgumentParser.parse_args

    def parse_then_stop(self, *args, **kwargs):
        real(self, *args, **kwargs)
        raise _Parsed

    monkeypatch.setattr(draccus.argparsing.ArgumentParser, "parse_args", parse_then_stop)


def _options(main) -> dict[str, str]:
    """``--flag`` -> its metavar (``int``, ``float``, ``str``, ``bool``, ``[float]``,
    ``tuple[float, float]``...) from the command's ``--help``."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit):
        main(["--help"])
    found = {}
    for line in out.getvalue().splitlines():
        m = re.match(r"^  (--[\w.]+) (\S+(?:, \S+)*)", line)
        if m and m.group(1) not in ("--help", "--config_path"):
            found[m.group(1)] = m.group(2)
    return found


def _hostile(metavar: str, tmp: Path) -> list[str]:
    """Values for an option of this metavar: every option also gets the wrong type."""
    fifo = tmp / "fifo"
    if not fifo.exists():
        os.mkfifo(fifo)
    anything = ["", "null", "{a: 1}", "[", "/dev/null", str(fifo), str(tmp)]
    numbers = ["nan", "inf", "-inf", "-1", "0", "1e300", "9" * 23, "1e-320", "0x10"]
    kind = metavar.strip("[]")
    if kind in ("int", "float"):
        return numbers + ["abc", "1.5", "true"] + anything[:4]
    if kind == "bool":
        return ["maybe", "2", "nan"] + anything[:4]
    if kind.startswith(("tuple", "list")):
        return ["[nan]", "[1e300]", "[-1]", "[inf, 1]", "[]", "[[1]]", "abc", "nan"] + anything[:4]
    return anything + ["nan", "-1", "x" * 5000, "../../" * 20]


def _answer(main, argv: list[str]) -> tuple[str, str]:
    """What the command did with ``argv``: ("accepted" | "refused", stderr)."""
    err = io.StringIO()

    def hang(*_):
        raise TimeoutError(f"no answer within {LIMIT_S} s")

    old = signal.signal(signal.SIGALRM, hang)
    signal.alarm(LIMIT_S)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            main(argv)
        return "accepted", err.getvalue()
    except _Parsed:
        return "accepted", err.getvalue()
    except SystemExit as e:
        text = err.getvalue().strip() or str(e.code)
        assert e.code == 2 or (e.code != 0 and isinstance(e.code, str)), (argv, e.code, text)
        return "refused", text
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


@pytest.mark.timeout(900)
@pytest.mark.parametrize("command", COMMANDS)
def test_every_option_takes_hostile_values_without_a_traceback(command, tmp_path):
    main = COMMANDS[command]
    options = _options(main)
    assert len(options) >= 2, f"{command}: no options found in --help"
    bad = []
    for flag, metavar in options.items():
        for value in _hostile(metavar, tmp_path):
            try:
                what, text = _answer(main, [f"{flag}={value}"])
                if value in NEVER:  # the spaced spelling gets the same checks
                    spaced, _ = _answer(main, [flag, value])
                    what = "accepted" if "accepted" in (what, spaced) else what
            except Exception as e:  # noqa: BLE001 - the finding: any traceback
                bad.append(f"{flag}={value[:30]!r}: {type(e).__name__}: {str(e)[:120]}")
                continue
            if what == "accepted" and value in NEVER and re.search(r"int|float", metavar):
                bad.append(f"{flag}={value[:30]!r}: a number option accepted it")
            if what == "refused" and len(text.splitlines()) != 1:
                bad.append(f"{flag}={value[:30]!r}: {len(text.splitlines())} lines: "
                           f"{text[:200]!r}")
    assert not bad, f"{command}: {len(bad)} value(s) without a one-line answer:\n" + \
        "\n".join(bad[:40])

"""Each default the manual states is the one the command builds.

The option tables of README.md and docs/training.md (a header with an ``option`` or
``flag`` column and a ``default`` column) are read row by row: the options named in the
first cell (``--steps``, ``--eval.trials``) are looked up in the config class the section
documents, and the default cell is compared with that field's default. A cell that says
``x → y`` states ``x`` (the field's value, which the command then resolves to ``y``); a
trailing ``(...)`` is a remark. Cells that describe instead of stating a value must be
listed in ``DESCRIBED``, so a new table row is either checked or consciously not.
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path
from typing import Any

import pytest

from msta.eval.apps.demo import DemoConfig
from msta.policies.teacher.config import SHIPPED_RMA_PPO
from msta.train.correct_config import CorrectConfig
from msta.train.train_config import TrainConfig

REPO = Path(__file__).resolve().parents[1]

#: (page, heading of the section holding the table) -> the config class its options set
TABLES: dict[tuple[str, str], type] = {
    ("README.md", "Two commands"): DemoConfig,
    ("docs/training.md", "Stage 1: `msta-train`"): TrainConfig,
    ("docs/training.md", "Stage 2: `msta-correct`"): CorrectConfig,
    ("docs/training.md", "Defaults and why"): CorrectConfig,
}
#: options whose default cell is a description, not a value
DESCRIBED = {"--dataset", "--policy.preset", "--eval.terrains", "--eval.levels"}


def option_rows(page: str, root: Path = REPO) -> list[tuple[str, int, list[str], str]]:
    """``(section heading, line, options, default cell)`` of each option-table row."""
    rows, heading, cols = [], "", None
    for n, line in enumerate((root / page).read_text(encoding="utf-8").splitlines(), 1):
        if m := re.match(r"#{1,6} (.+)", line):
            heading, cols = m.group(1).strip(), None
        if not line.startswith("|"):
            cols = None
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if cols is None:
            lower = [c.lower() for c in cells]
            if lower and lower[0] in ("option", "flag") and "default" in lower:
                cols = (0, lower.index("default"))
            else:
                cols = ()
            continue
        if not cols or set(line) <= set("|-: "):
            continue
        options = re.findall(r"`(--[\w.*]+)`", cells[cols[0]])
        if options:
            rows.append((heading, n, options, cells[cols[1]]))
    return rows


def stated_values(cell: str, count: int) -> list[Any] | None:
    """The values a default cell states (one per option), or None if it only describes."""
    text = cell.split("→")[0].strip()
    text = re.sub(r"\s*\([^)]*\)\s*$", "", text).strip().replace("`", "")
    parts = [text] if count == 1 else [p.strip() for p in text.split(",")]
    if len(parts) != count:
        return None
    values = []
    for part in parts:
        if part in ("true", "false", "null", '""'):  # '""': an empty text
            values.append(json.loads(part))
        elif re.fullmatch(r"\[[^\]]*\]", part):
            values.append([float(v) for v in part.strip("[]").split(",") if v.strip()])
        elif re.fullmatch(r"-?[\d.]+(e-?\d+)?", part):
            values.append(float(part))
        elif count == 1 and re.fullmatch(r"-?[\d.]+(, -?[\d.]+)+", part):
            values.append([float(v) for v in part.split(",")])
        elif re.fullmatch(r"[\w/.-]+", part):
            values.append(part)
        else:
            return None
    return values


def field_default(cls: type, dotted: str) -> Any:
    """The default of ``--a.b.c`` in ``cls``: a field's default, or its factory's product."""
    obj: Any = cls
    for name in dotted.split("."):
        f = {f.name: f for f in dataclasses.fields(obj)}.get(name)
        if f is None:  # a property of an instance, e.g. a policy config's registered ``type``
            obj = getattr(obj, name)
        elif f.default is not dataclasses.MISSING:
            obj = f.default
        elif f.default_factory is not dataclasses.MISSING:
            obj = f.default_factory()
        else:
            raise KeyError(f"{cls.__name__}.{dotted} has no default")
    return obj


def same(stated: Any, actual: Any) -> bool:
    if isinstance(actual, (tuple, list)):
        return isinstance(stated, list) and list(map(float, actual)) == stated
    if isinstance(actual, bool) or actual is None:
        return stated is actual
    if isinstance(actual, (int, float)):
        return isinstance(stated, float) and float(actual) == stated
    return str(actual) == stated


def documented_defaults() -> list[tuple[str, type, str, str]]:
    """``(where, config class, option, default cell)`` for every documented table row."""
    out = []
    for page in sorted({page for page, _ in TABLES}):
        for heading, n, options, cell in option_rows(page):
            cls = TABLES.get((page, heading))
            if cls is None:
                continue
            out.extend((f"{page}:{n}", cls, opt, cell) for opt in options)
    return out


def check_row(cls: type, options: list[str], cell: str) -> list[str]:
    """Mismatches of one row, as sentences; [] when the row states its defaults right."""
    if options == ["--teacher.*"]:
        teacher = field_default(cls, "teacher")
        ok = teacher.type == "rma" and Path(teacher.path) == SHIPPED_RMA_PPO
        return [] if ok and "rma_ppo" in cell else [f"teacher default is {teacher}"]
    if set(options) <= DESCRIBED:
        return []
    values = stated_values(cell, len(options))
    if values is None:
        return [f"{options}: cannot read a value in {cell!r} (state one, or add to DESCRIBED)"]
    bad = []
    for opt, value in zip(options, values):
        actual = field_default(cls, opt[2:])
        if not same(value, actual):
            bad.append(f"{opt}: the docs say {value!r}, {cls.__name__} builds {actual!r}")
    return bad


# ----- the checks see what they look for --------------------------------------------------

def test_the_parser_reads_tables_and_sees_a_wrong_default(tmp_path):
    (tmp_path / "p.md").write_text(
        "## Stage 1\n\n| flag | default | meaning |\n|---|---|---|\n"
        "| `--steps`, `--batch_size` | 2000, 64 | x |\n| `--mask_ratio` | null → 0.75 | y |\n"
        "| `--eval_every` | 500 (off with 0) | z |\n\n| other | default |\n|---|---|\n"
        "| `--lr` | 1 | not an option table |\n")
    rows = option_rows("p.md", tmp_path)
    assert [(r[0], r[2], r[3]) for r in rows] == [
        ("Stage 1", ["--steps", "--batch_size"], "2000, 64"),
        ("Stage 1", ["--mask_ratio"], "null → 0.75"),
        ("Stage 1", ["--eval_every"], "500 (off with 0)"),
    ]
    assert check_row(TrainConfig, ["--steps", "--batch_size"], "2000, 64") == []
    assert check_row(TrainConfig, ["--mask_ratio"], "null → policy's (0.75)") == []
    assert check_row(TrainConfig, ["--steps"], "3000") == [
        "--steps: the docs say 3000.0, TrainConfig builds 2000"]
    assert check_row(DemoConfig, ["--rollout_mask_ratios"], "`[0,0.5]`") == []
    assert check_row(DemoConfig, ["--rollout_mask_ratios"], "`[0.5]`") != []
    assert check_row(DemoConfig, ["--output_dir"], "`outputs/demo`") == []
    assert check_row(CorrectConfig, ["--keep_unfinished"], "false") != []
    assert check_row(CorrectConfig, ["--eval.mask_ratios"], "0, 0.5") == []
    assert check_row(CorrectConfig, ["--beta"], "a lot") != []


# ----- the repository ---------------------------------------------------------------------

def test_every_documented_table_is_found():
    found = {(page, heading) for page in {p for p, _ in TABLES}
             for heading, *_ in option_rows(page)}
    assert set(TABLES) <= found, f"tables not found: {set(TABLES) - found}"


@pytest.mark.parametrize("page,heading", sorted(TABLES))
def test_documented_defaults_are_the_ones_the_command_builds(page, heading):
    cls = TABLES[(page, heading)]
    bad = [f"{page}:{n}: {msg}" for h, n, options, cell in option_rows(page) if h == heading
           for msg in check_row(cls, options, cell)]
    assert not bad, "\n".join(bad)

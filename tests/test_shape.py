"""Sizes a reader can hold (house rule 1): every Python file of the packages (the LeRobot
plugins included) has at most 500 lines, every function and method at most 60 (``def``
line to last line, decorators not counted). A failure lists every offender with its size."""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("msta_data", "policies", "collect", "train", "eval")
MAX_FILE_LINES = 500
MAX_FUNCTION_LINES = 60


def sources() -> list[Path]:
    files = sorted(p for pkg in PACKAGES for p in (REPO / pkg).rglob("*.py")
                   if "__pycache__" not in p.parts)
    assert len(files) > 50, files  # the walk found the packages
    return files


def long_functions(path: Path, root: Path = REPO) -> list[str]:
    """``path:line name (N lines)`` (``path`` relative to ``root``) for each function or
    method over the limit."""
    tree = ast.parse(path.read_text(), filename=str(path))
    rel = path.relative_to(root)
    return [f"{rel}:{node.lineno} {node.name} ({node.end_lineno - node.lineno + 1} lines)"
            for node in ast.walk(tree)
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
            and node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES]


def long_files(paths: list[Path], root: Path = REPO) -> list[str]:
    """``path (N lines)`` for each file over the limit."""
    return [f"{p.relative_to(root)} ({n} lines)" for p in paths
            if (n := len(p.read_text().splitlines())) > MAX_FILE_LINES]


def test_no_file_over_500_lines():
    long = long_files(sources())
    assert not long, f"files over {MAX_FILE_LINES} lines:\n" + "\n".join(long)


def test_no_function_over_60_lines():
    long = [row for p in sources() for row in long_functions(p)]
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines:\n" + "\n".join(long)


def test_the_checks_see_an_offender(tmp_path):
    """The limits bite: a 61-line function and a 501-line file are listed with their size."""
    body = "\n".join(f"    x{i} = {i}" for i in range(60))
    src = tmp_path / "long.py"
    src.write_text(f"def short():\n    pass\n\n\ndef long():\n{body}\n")
    assert long_functions(src, tmp_path) == ["long.py:5 long (61 lines)"]
    assert long_files([src], tmp_path) == []  # 66 lines
    src.write_text("x = 1\n" * 501)
    assert long_files([src], tmp_path) == ["long.py (501 lines)"]

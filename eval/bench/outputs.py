"""The benchmarks' ``--output_dir``: claimed before a benchmark replaces what it wrote there
(:mod:`msta.data.output_dirs`), refused in one line when it holds someone else's files."""

from __future__ import annotations

from pathlib import Path

from msta.data.output_dirs import command_output_dir


def own_output(path: str | Path, prog: str, names: frozenset[str],
               prefixes: tuple[str, ...] = (), sign: frozenset[str] = frozenset()) -> Path:
    """``path`` claimed for benchmark ``prog`` (its entries from before the marker: ``names``
    and names starting with one of ``prefixes``, one of them in ``sign`` or prefixed);
    exit 2 with one line otherwise."""
    path = Path(path)
    prefixed = {p.name for p in path.iterdir() if p.name.startswith(prefixes)} \
        if path.is_dir() and prefixes else set()
    return command_output_dir(path, prog, prog, legacy=frozenset(names | prefixed),
                              sign=frozenset(sign | prefixed))

"""msta-export's per-sample removal inputs and the guard it copies along (docs/deploy.md,
"Exporting with a guard"): which sensors get an ``absent_<sensor>`` input, the random removal
masks of the parity check, the guard's files and spec entry."""

from __future__ import annotations

import shutil
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from msta.data import sensors as registry
from msta.policies.guard import INPUT_SENSORS
from msta.policies.guard_file import GUARD_ARRAYS, GUARD_JSON, load_guard, save_guard

#: ONNX / TorchScript input name of a sensor's per-sample channel removal
ABSENT_PREFIX = "absent_"


def absent_masks(sensors: Sequence[str], n: int, seed: int = 0, p: float = 0.25
                 ) -> dict[str, np.ndarray]:
    """Random per-sample removal masks ``{sensor: (n, dim) bool}``, each channel removed
    with probability ``p``; the first sample removes nothing (the plain student)."""
    rng = np.random.default_rng([seed, 0xAB5E])
    out = {s: rng.random((n, registry.get(s).dim)) < p for s in sensors}
    for m in out.values():
        m[:1] = False
    return out


def trace_masks(sensors: Sequence[str]) -> dict[str, np.ndarray]:
    """Example masks to trace with, ``{sensor: (1, dim) bool}``: channel 0 removed (a mask
    that removes nothing would trace the plain student's path)."""
    return {s: np.arange(registry.get(s).dim)[None] == 0 for s in sensors}


def removal_spec(absent: Sequence[str], guard_dir: str | Path | None, out: Path
                 ) -> dict[str, Any]:
    """spec.json's ``absent_inputs`` (when any) and ``guard`` (when ``guard_dir``, whose
    files are copied into ``out``)."""
    spec: dict[str, Any] = {}
    if absent:
        spec["absent_inputs"] = [
            {"name": ABSENT_PREFIX + n, "sensor": n, "shape": ["batch", registry.get(n).dim],
             "dtype": "bool", "meaning": "True removes that channel from the window"}
            for n in absent]
    if guard_dir is not None:
        spec["guard"] = copy_guard(Path(guard_dir), out)
    return spec


def copy_guard(src: Path, out: Path) -> dict[str, Any]:
    """Copy a saved guard's files into the export folder; its spec.json entry (what the
    guard's loader reads, not the readable copy in guard.json)."""
    guard = load_guard(src)
    if guard is None:
        raise FileNotFoundError(f"{src}: no guard saved there ({GUARD_ARRAYS})")
    if not (src / GUARD_JSON).is_file():  # the arrays carry the settings: write both again
        save_guard(guard, out)
    for name in (GUARD_JSON, GUARD_ARRAYS):
        if (src / name).is_file() and (src / name).resolve() != (out / name).resolve():
            shutil.copyfile(src / name, out / name)
    return {"files": [GUARD_JSON, GUARD_ARRAYS], "reads": list(INPUT_SENSORS),
            "flags": list(guard.sensors), "dt": guard.dt,
            "use": "msta.policies.guard_file.load_guard(<export dir>).update(readings) each "
                   "step; its flags of the sensors with an absent_<sensor> input go there "
                   "(latched until reset at an episode start)"}


def absent_inputs(option: str, checkpoint: Path, names: Sequence[str]
                   ) -> tuple[tuple[str, ...], Path | None]:
    """``--absent_inputs`` -> (sensors with a removal input, the guard's folder or None)."""
    guard = load_guard(checkpoint)
    if option == "auto":
        if guard is None:
            return (), None
        return tuple(n for n in names if n in guard.sensors), checkpoint
    if guard is not None and option == "none":
        print("msta-export: --absent_inputs=none: the checkpoint's guard is left out (the "
              "exported student could not take its flags)", file=sys.stderr)
    if option == "none":
        return (), None
    chosen = tuple(n.strip() for n in option.split(",") if n.strip())
    bad = [n for n in chosen if n not in names]
    if bad or not chosen:
        raise ValueError(f"--absent_inputs must be auto, none or a comma list of exported "
                         f"sensors {list(names)}, got {option!r}")
    return tuple(n for n in names if n in chosen), checkpoint if guard is not None else None

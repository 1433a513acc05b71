"""A guard on disk: ``guard.safetensors`` (the arrays, with the settings in its header) and
``guard.json`` (the same settings, for a reader).

Saving writes the arrays file first, whole, under a temporary name and renames it: that
rename is the one commit point, and the settings travel inside it, so a process killed at
any moment leaves either the old guard or the new one, never new arrays with old settings.
``guard.json`` follows as a readable copy; loading reads the settings from the arrays
file's header (a guard saved before the header existed: from ``guard.json``).

Every file is checked before use: a malformed or hostile guard is one line naming the file
(:class:`GuardFileError`), and thresholds, scales and the control period must be finite and
positive, so no file can switch the guard off silently.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, fields
from pathlib import Path
from typing import Any

import numpy as np
from safetensors import SafetensorError, safe_open
from safetensors.numpy import save_file

from msta.data.sensors import PHYSICAL_SENSORS
from msta.policies.guard import FORMAT, LEGACY_CONFIG, GuardConfig, SensorGuard

GUARD_JSON = "guard.json"
GUARD_ARRAYS = "guard.safetensors"
#: The largest guard.json read (a fitted one is a few kB).
MAX_JSON_BYTES = 1 << 20
_HEADER_KEY = "msta_guard"


class GuardFileError(ValueError):
    """A saved guard cannot be used (the file and the reason named)."""


def save_guard(guard: SensorGuard, directory: str | Path) -> Path:
    """Write ``guard.safetensors`` then ``guard.json`` into ``directory`` (a checkpoint
    folder), each atomically (module docstring); returns the json's path."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"format": FORMAT, "config": asdict(guard.cfg), "sensors": list(guard.sensors),
            "dt": guard.dt, "statistics": guard.names}
    text = json.dumps(meta, indent=1) + "\n"
    for name, write in (
            (GUARD_ARRAYS, lambda p: save_file(
                {k: guard.stats[k].copy(order="C") for k in guard.stats}, str(p),
                metadata={_HEADER_KEY: text})),
            (GUARD_JSON, lambda p: p.write_text(text))):
        tmp = out / f"{name}.tmp"
        write(tmp)
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, out / name)
    return out / GUARD_JSON


def _settings(directory: Path) -> tuple[dict[str, Any], Path]:
    """The saved settings (from the arrays' header, else guard.json) and where they came
    from."""
    arrays = directory / GUARD_ARRAYS
    try:
        with safe_open(str(arrays), framework="np") as f:
            header = (f.metadata() or {}).get(_HEADER_KEY)
    except (SafetensorError, OSError, ValueError) as e:
        raise GuardFileError(f"{arrays}: not a readable safetensors file ({e})") from None
    if header is not None:
        text, source = header, arrays
    else:
        source = directory / GUARD_JSON
        if not source.is_file() or source.stat().st_size > MAX_JSON_BYTES:
            raise GuardFileError(f"{source}: missing, not a regular file or over "
                                 f"{MAX_JSON_BYTES} bytes")
        text = source.read_text(errors="replace")
    try:
        meta = json.loads(text)
    except (ValueError, RecursionError) as e:
        raise GuardFileError(f"{source}: not valid JSON ({str(e)[:80]})") from None
    return meta, source


def _check_meta(meta: Any, source: Path) -> tuple[GuardConfig, tuple[str, ...], float]:
    if not isinstance(meta, dict):
        raise GuardFileError(f"{source}: the guard's settings must be a JSON object")
    if meta.get("format") != FORMAT:
        raise GuardFileError(f"{source}: guard format {str(meta.get('format'))[:20]!r}, "
                             f"expected {FORMAT}")
    config, sensors, dt = meta.get("config"), meta.get("sensors"), meta.get("dt")
    if not isinstance(config, dict):
        raise GuardFileError(f"{source}: 'config' must be an object of guard settings")
    unknown = sorted(str(k)[:30] for k in set(config) - {f.name for f in fields(GuardConfig)})
    if unknown:
        raise GuardFileError(f"{source}: unknown guard config keys {unknown}")
    kinds = {f.name: type(getattr(GuardConfig(), f.name)) for f in fields(GuardConfig)}
    for key, value in config.items():
        want = kinds[key]
        ok = (isinstance(value, bool) if want is bool
              else isinstance(value, int) and not isinstance(value, bool) if want is int
              else isinstance(value, int | float) and not isinstance(value, bool))
        if not ok:
            raise GuardFileError(f"{source}: guard setting {key!r} must be a {want.__name__}, "
                                 f"got {str(value)[:30]!r}")
    try:
        cfg = GuardConfig(**{**LEGACY_CONFIG, **config})
    except (TypeError, ValueError, OverflowError) as e:
        raise GuardFileError(f"{source}: {e}") from None
    if (not isinstance(sensors, list) or not sensors
            or not all(isinstance(s, str) and s in PHYSICAL_SENSORS for s in sensors)):
        raise GuardFileError(f"{source}: 'sensors' must be a list of {list(PHYSICAL_SENSORS)}")
    if isinstance(dt, bool) or not isinstance(dt, int | float):
        raise GuardFileError(f"{source}: 'dt' must be a number of seconds")
    return cfg, tuple(sensors), float(dt)


def load_guard(directory: str | Path, num_envs: int = 1) -> SensorGuard | None:
    """The guard saved in a checkpoint folder, or None when the folder has none.

    Raises:
        GuardFileError: one line naming the file: not a guard msta can use (malformed
            settings or arrays, a threshold, scale or period that is not finite and
            positive, arrays of the wrong shape).
    """
    directory = Path(directory)
    if not (directory / GUARD_JSON).is_file() and not (directory / GUARD_ARRAYS).exists():
        return None
    if not (directory / GUARD_ARRAYS).is_file():
        raise GuardFileError(f"{directory / GUARD_ARRAYS}: missing or not a regular file, "
                             f"beside {GUARD_JSON}; fit the guard again (msta-guard fit)")
    meta, source = _settings(directory)
    cfg, sensors, dt = _check_meta(meta, source)
    try:
        with safe_open(str(directory / GUARD_ARRAYS), framework="np") as f:
            arrays = {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118
        guard = SensorGuard(cfg, arrays, sensors, num_envs, dt)
    except (SafetensorError, KeyError, ValueError, TypeError) as e:
        raise GuardFileError(f"{directory / GUARD_ARRAYS}: {str(e).strip(chr(39))}") from None
    if not np.isfinite(guard.stats["threshold"]).all():  # an infinite one never fires
        raise GuardFileError(f"{directory / GUARD_ARRAYS}: guard array 'threshold' must be "
                             "finite (an infinite threshold switches its statistic off)")
    return guard

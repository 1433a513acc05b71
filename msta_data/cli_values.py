"""A command line's values before draccus reads them (every value is YAML to draccus): a
text option's value is taken as typed, a number option's is checked for NaN, infinity and
integers beyond 64 bits. Also the config classes' field types and option groups."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import typing
from pathlib import Path
from typing import Any

import yaml


def field_types(cls: type) -> dict[str, Any]:
    try:
        hints = typing.get_type_hints(cls)
    except Exception:  # noqa: BLE001 - unresolvable annotations: fall back to the raw ones
        hints = {f.name: f.type for f in dataclasses.fields(cls)}
    return {f.name: hints.get(f.name, f.type) for f in dataclasses.fields(cls)}


def dataclasses_of(tp: Any) -> list[type]:
    """The dataclass(es) a field's type can hold: itself, an Optional's argument, or every
    registered choice of a draccus choice type (``--policy.type=...``)."""
    for arg in typing.get_args(tp) or (tp,):
        if isinstance(arg, type) and dataclasses.is_dataclass(arg):
            choices = getattr(arg, "get_known_choices", None)
            if choices is not None:
                return [arg, *choices().values()]
            return [arg]
    return []


def prepare_values(args: list[str], parser: argparse.ArgumentParser,
                     config_class: type) -> list[str]:
    """A text option's value is taken as typed: draccus reads every value as YAML, so
    ``--root=null`` gave None, ``--root=[a, b]`` a folder named ``['a', 'b']``, ``yes`` the
    text ``True`` and ``bias:3:encoder:`` a mapping. Each ``--<text option>=<value>`` is
    quoted for YAML here. Any option's value with a control character (a newline, which also
    let a second YAML document in) is refused in one line, and a number option's is checked
    (:func:`_check_numbers`)."""
    options = {s: a for a in parser._actions for s in a.option_strings}
    groups = _group_dests(config_class)
    out: list[str] = []
    i = 0
    while i < len(args):
        arg = args[i]
        i += 1
        flag, sep, value = arg.partition("=")
        action = options.get(flag)
        if action is None or not flag.startswith("--"):
            out.append(arg)
            continue
        if not sep and action.nargs != 0:  # --option value: checked as --option=value
            if i == len(args) or args[i].startswith("--"):
                out.append(arg)  # argparse names the missing value
                continue
            sep, value, i = "=", args[i], i + 1
        if not sep:
            out.append(arg)
            continue
        _check_text(flag, value)
        if _numeric(action.type):
            _check_numbers(flag, value)
        if action.type is not str or flag == "--config_path" or action.dest in groups:
            out.append(f"{flag}={value}")
            continue
        if action.dest.rsplit(".", 1)[-1] in FOLDER_OPTIONS and value:
            path = Path(value)
            if path.exists() and not path.is_dir():
                raise ValueError(f"{flag}={value} is not a folder (a file, a device or a FIFO "
                                 "is there); choose a folder")
        # a YAML double-quoted scalar; characters beyond U+FFFF stay themselves (escaped,
        # they would come back as two lone surrogates)
        out.append(f"{flag}={json.dumps(value, ensure_ascii=False)}")
    return out


#: Options that name a folder a command writes into or reads from: one naming a file, a
#: device or a FIFO is refused when the command line is read.
FOLDER_OPTIONS = ("output_dir", "root")


def _check_text(flag: str, value: str) -> None:
    """No option's value holds a control character (C0, DEL, C1), a Unicode line or
    paragraph separator or a lone surrogate (a newline let ``---`` start a second YAML
    document; a task or terrain name with one broke the dataset card; YAML folds U+0085 to a
    space)."""
    if any(ord(c) < 32 or 127 <= ord(c) <= 159 or c in "\u2028\u2029"
           or 0xD800 <= ord(c) <= 0xDFFF for c in value):
        raise ValueError(f"{flag} must be text without control characters, got "
                         f"{value[:40]!r}")


def _numeric(tp: Any) -> bool:
    """Whether an option's type holds numbers (``int``, ``float | None``, ``tuple[float,
    ...]``)."""
    if tp in (int, float):
        return True
    return any(_numeric(arg) for arg in typing.get_args(tp) if arg is not type(None))


def _check_numbers(flag: str, value: str) -> None:
    """A number option's value holds no NaN, no infinity (``inf``, ``.inf``, ``1e999``) and
    no integer beyond 64 bits: one line instead of a value that breaks the command later."""
    try:
        data = yaml.safe_load(value)
    except yaml.YAMLError:
        return  # draccus names the malformed value
    stack = [data]
    while stack:
        item = stack.pop()
        if isinstance(item, list | tuple):
            stack.extend(item)
            continue
        if isinstance(item, str):
            try:
                item = float(item.strip())
            except ValueError:
                continue
        if isinstance(item, float) and not math.isfinite(item):
            raise ValueError(f"{flag}={value} must be a finite number")
        if isinstance(item, int) and not isinstance(item, bool) and abs(item) >= 2**63:
            raise ValueError(f"{flag}={value} must be within the 64-bit integers msta takes")


def _group_dests(cls: type, prefix: str = "") -> set[str]:
    """Dotted names of the nested config groups of ``cls`` (``env``, ``env.terrain``)."""
    out: set[str] = set()
    for name, tp in field_types(cls).items():
        for sub in dataclasses_of(tp):
            out |= {prefix + name} | _group_dests(sub, f"{prefix}{name}.")
    return out

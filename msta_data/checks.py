"""Range and finiteness checks every command's config makes: one-line ``ValueError``s that
name the option as the user spells it (NaN and infinity never pass)."""

from __future__ import annotations

import dataclasses
import math
import numbers
from typing import Any


def check_number(name: str, value: Any, minimum: float | None = None,
                 maximum: float | None = None, *, above: bool = False, why: str = "") -> None:
    """The range check every command's config makes: raise a one-line
    ``ValueError("<name>=<value> must be ...")`` unless ``value`` is a finite number (NaN
    and infinity never pass, a bool is not a number) within the bounds.

    Args:
        name: the option, as the user spells it (``batch_size``, ``env.num_envs``).
        value: its value.
        minimum: the lowest value allowed (None: no lower bound).
        maximum: the highest value allowed (None: no upper bound).
        above: ``value`` must be strictly greater than ``minimum``.
        why: why the upper bound is what it is, appended to the message.
    """
    ok = (isinstance(value, numbers.Real) and not isinstance(value, bool)
          and math.isfinite(value))
    if ok and (minimum is None or value > minimum or (value == minimum and not above)) and (
            maximum is None or value <= maximum):
        return
    low = "" if minimum is None else f"{'>' if above else '>='} {minimum}"
    if maximum is None:
        bound = low
    elif minimum is None:
        bound = f"<= {maximum}"
    else:
        bound = f"in {'(' if above else '['}{minimum}, {maximum}]"
    finite = "" if ok else "a finite number "
    raise ValueError(f"{name}={value} must be {finite}{bound}" + (f" ({why})" if why else ""))


def check_finite_fields(config: Any, prefix: str = "") -> None:
    """Raise a one-line ``ValueError("<prefix><name>=nan must be a finite number")`` for the
    first float of the dataclass ``config`` (nested dataclasses, tuples, lists and dict values
    included) that is NaN or infinite: options without a range check of their own (a reward
    scale, a PD gain, a command range) must not reach the simulator as NaN either."""
    for f in dataclasses.fields(config):
        _check_finite(f"{prefix}{f.name}", getattr(config, f.name))


def _check_finite(name: str, value: Any) -> None:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        check_finite_fields(value, name + ".")
    elif isinstance(value, tuple | list):
        for v in value:
            _check_finite(name, v)
    elif isinstance(value, dict):
        for k, v in value.items():
            _check_finite(f"{name}.{k}", v)
    elif isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"{name}={value} must be a finite number")


def check_at_least(config: Any, minimum: float, *names: str, maximum: float | None = None,
                   why: str = "") -> None:
    """:func:`check_number` on each of the config's fields ``names``: ``ValueError("<name>=
    <value> must be >= <minimum>")`` for the first one below ``minimum`` (or above
    ``maximum``, or not finite)."""
    for name in names:
        check_number(name, getattr(config, name), minimum, maximum, why=why)

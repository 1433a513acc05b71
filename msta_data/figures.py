"""How a figure and its 95 % interval are written: msta-eval's report.md, msta-correct's
round table and the model cards all print them through :func:`fmt_ci`.
"""

from __future__ import annotations

import math


def fmt(v: float | None, digits: int = 2) -> str:
    """``v`` with ``digits`` decimals, or ``n/a`` (None or NaN)."""
    return "n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{digits}f}"


def fmt_ci(v: float | None, ci: list[float] | tuple[float, float] | None, digits: int = 2) -> str:
    """``0.85 ±0.10`` (symmetric 95 % interval), ``0.80 (0.49–0.94)`` (Wilson), ``0.85``
    (one trial: no interval) or ``n/a``."""
    text = fmt(v, digits)
    if v is None or not ci or text == "n/a":
        return text
    lo, hi = ci
    if math.isclose(hi - v, v - lo, rel_tol=1e-6, abs_tol=1e-9):
        return f"{text} ±{(hi - lo) / 2:.{digits}f}"
    return f"{text} ({lo:.{digits}f}–{hi:.{digits}f})"

"""``--max_minutes``: stop a long command at a safe point and continue it on the next call.

A machine lent for a few minutes per command (the project's GPU machine: 10 minutes a
command) runs a long job as a series of calls of the same command. Every long msta command
(msta-train, msta-correct, msta-compare, msta-eval, msta-repro) takes ``--max_minutes``:
once that many minutes have passed it stops at the next safe point (after an optimizer step,
with a checkpoint saved; after a finished stage-2 phase; after a round of evaluation trials),
prints one line saying so and exits with :data:`EXIT_STOPPED` (75, ``EX_TEMPFAIL``: "run
again"). A call therefore lasts ``max_minutes`` plus at most one unit of work, and does at
least one unit (so a series of calls always finishes). Exit code 0 means the job is
finished, 2 a bad input.

    until msta-repro --scale=paper --max_minutes=7; do [ $? -eq 75 ] || exit 1; done
"""

from __future__ import annotations

import time

#: Exit status of a command stopped by ``--max_minutes`` (sysexits.h EX_TEMPFAIL).
EXIT_STOPPED = 75


class TimeLimitReached(Exception):
    """``--max_minutes`` passed; the work done so far is saved and the same command
    (with its resume option) continues it."""


def deadline_after(max_minutes: float) -> float | None:
    """The ``time.monotonic()`` deadline ``max_minutes`` from now (None: no limit)."""
    if max_minutes < 0:
        raise ValueError(f"max_minutes={max_minutes} must be >= 0 (0: no limit)")
    return time.monotonic() + max_minutes * 60.0 if max_minutes > 0 else None


def passed(deadline: float | None) -> bool:
    return deadline is not None and time.monotonic() >= deadline


def check_deadline(deadline: float | None, where: str) -> None:
    """Raise :class:`TimeLimitReached` (``where``: the safe point, for the message) when
    ``deadline`` has passed."""
    if passed(deadline):
        raise TimeLimitReached(where)


def minutes_left(deadline: float | None) -> float:
    """``max_minutes`` for a sub-command (0: no limit). Never below a moment: past the
    deadline the sub-command still does one unit of work before it stops, so every call
    of a command makes progress."""
    if deadline is None:
        return 0.0
    return max((deadline - time.monotonic()) / 60.0, 1e-6)


def stop(prog: str, e: TimeLimitReached, again: str = "the same command") -> None:
    """Print the one-line stop message and exit with :data:`EXIT_STOPPED`."""
    print(f"{prog}: stopped ({e}): --max_minutes reached; run {again} again to continue",
          flush=True)
    raise SystemExit(EXIT_STOPPED)


__all__ = ["EXIT_STOPPED", "TimeLimitReached", "check_deadline", "deadline_after",
           "minutes_left", "passed", "stop"]

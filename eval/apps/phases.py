"""One line per phase of a long command (msta-compare, msta-repro) with the elapsed time, and
each phase's duration in ``timing.json``, kept across calls that ``--max_minutes`` stopped."""

from __future__ import annotations

import json
import time
from pathlib import Path

from msta.data.budget import check_deadline, minutes_left


class PhaseLog:
    """One line per phase with the elapsed time; phase durations go to ``output_dir/timing.json``."""

    def __init__(self, out: Path, prog: str = "msta-compare",
                 deadline: float | None = None) -> None:
        self.prog, self.deadline = prog, deadline
        self.started = False  # a phase has started in this process
        self.path = out / "timing.json"
        self.timing: dict[str, float] = json.loads(self.path.read_text()) \
            if self.path.exists() else {}
        # seconds spent in unfinished phases by calls that --max_minutes stopped
        self.partial_path = out / "timing_partial.json"
        self.partial: dict[str, float] = json.loads(self.partial_path.read_text()) \
            if self.partial_path.exists() else {}
        self.current: tuple[str, float] | None = None
        self.t0 = time.perf_counter()

    def start(self, phase: str, detail: str = "") -> float:
        """Announce a phase (past ``--max_minutes``, raises :class:`TimeLimitReached`
        instead, unless it is this process's first phase)."""
        if self.started:
            check_deadline(self.deadline, f"before {phase}")
        self.started = True
        self.current = (phase, time.perf_counter())
        print(f"[{self.prog} {self._clock()}] {phase}{': ' + detail if detail else ''}",
              flush=True)
        return time.perf_counter()

    def done(self, phase: str, t_start: float) -> None:
        dt = time.perf_counter() - t_start
        self.current = None
        self.timing[phase] = round(dt + self.partial.pop(phase, 0.0), 1)
        self.path.write_text(json.dumps(self.timing, indent=1) + "\n")
        self.partial_path.write_text(json.dumps(self.partial, indent=1) + "\n")
        print(f"[{self.prog} {self._clock()}] {phase}: done in {dt:.0f} s", flush=True)

    def stopped(self) -> None:
        """Keep the time the running phase has had so far (``--max_minutes`` stopped it):
        the call that finishes the phase adds it to that phase's time."""
        if self.current is not None:
            phase, t = self.current
            self.partial[phase] = round(self.partial.get(phase, 0.0) + time.perf_counter() - t, 1)
            self.partial_path.write_text(json.dumps(self.partial, indent=1) + "\n")
            self.current = None

    def minutes_left(self) -> float:
        """``--max_minutes`` for the running phase's sub-command (0: no limit)."""
        return minutes_left(self.deadline)

    def _clock(self) -> str:
        s = int(time.perf_counter() - self.t0)
        return f"{s // 60:02d}:{s % 60:02d}"

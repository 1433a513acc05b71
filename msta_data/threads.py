"""How many CPU threads a process should compute with, when the user does not say.

torch (and OpenMP under it) takes every core by default. On a machine another job already
keeps busy, its threads then wait on each other: msta-train ran 30x slower with the default
than with one thread. :func:`auto_threads` gives each process the cores nobody else is using,
shared among the processes of the run:

    threads = max(1, (cores - busy) // processes)

``cores`` are the cores this process may run on (its CPU affinity, so a container's or
``taskset``'s limit counts), ``busy`` how many of those cores other work keeps busy now: the
kernel's busy time on exactly those CPUs over ~0.1 s (``/proc/stat``) less this process's
own (``/proc/self/stat``), rounded to the nearest whole core (the load average is not used:
it counts the whole host, and a job that ended a minute ago, this command's own previous
runs included), and ``processes`` the run's processes on this machine (torchrun's
``LOCAL_WORLD_SIZE``; 1 otherwise). Where /proc is missing, the 1-minute load average
stands in. Every ``--num_threads`` option takes 0 for this rule (the default) or a count.
``make bench-threads`` measures the rule against fixed counts on an idle and a loaded
machine.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path


def usable_cores() -> int:
    """The cores this process may run on (its affinity where the OS has one)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


#: /proc/stat's per-CPU columns: user nice system idle iowait irq softirq steal
_IDLE = (3, 4)
_STAT = Path("/proc/stat")


def cpu_times(stat: str, cpus: set[int]) -> tuple[int, int]:
    """(busy, total) clock ticks of ``cpus`` summed from a /proc/stat text."""
    busy = total = 0
    for line in stat.splitlines():
        name, *values = line.split()
        if not (name.startswith("cpu") and name[3:].isdigit() and int(name[3:]) in cpus):
            continue
        ticks = [int(v) for v in values[:8]]
        total += sum(ticks)
        busy += sum(v for i, v in enumerate(ticks) if i not in _IDLE)
    return busy, total


def _own_ticks() -> int:
    """This process's user + system clock ticks (/proc/self/stat fields 14 and 15)."""
    fields = Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()
    return int(fields[11]) + int(fields[12])


def busy_cores(interval_s: float = 0.1) -> float:
    """Cores of this process's affinity that other work keeps busy now (module docstring)."""
    try:
        cpus = os.sched_getaffinity(0)
        busy0, total0 = cpu_times(_STAT.read_text(), cpus)
        own0 = _own_ticks()
        time.sleep(interval_s)
        busy1, total1 = cpu_times(_STAT.read_text(), cpus)
        own1 = _own_ticks()
    except (OSError, ValueError, IndexError, AttributeError):
        return float(os.getloadavg()[0]) if hasattr(os, "getloadavg") else 0.0
    per_cpu = max(total1 - total0, 1) / len(cpus)  # ticks of one CPU over the interval
    return max(0.0, (busy1 - busy0 - (own1 - own0)) / per_cpu)


def run_processes() -> int:
    """The processes of this run on this machine: torchrun's ``LOCAL_WORLD_SIZE``, else 1."""
    try:
        return max(1, int(os.environ.get("LOCAL_WORLD_SIZE", "1")))
    except ValueError:
        return 1


def auto_threads(processes: int | None = None, cores: int | None = None,
                 busy: float | None = None) -> int:
    """Threads for one process (module docstring).

    Args:
        processes: the run's processes sharing this machine (None: :func:`run_processes`).
        cores: usable cores (None: :func:`usable_cores`).
        busy: cores other work keeps busy (None: :func:`busy_cores`).
    """
    processes = run_processes() if processes is None else max(1, processes)
    cores = usable_cores() if cores is None else cores
    busy = busy_cores() if busy is None else busy
    free = cores - min(int(busy + 0.5), cores)
    return max(1, free // processes)


def max_threads() -> int:
    """The most threads an option may ask for: 4 per usable core (at least 8)."""
    return max(8, 4 * usable_cores())


def check_threads(value: int, name: str = "num_threads") -> None:
    """One-line ValueError unless 0 (the rule) <= ``value`` <= :func:`max_threads`."""
    if not 0 <= value <= max_threads():
        raise ValueError(f"{name}={value} must be in [0, {max_threads()}] (0: from the free "
                         f"cores; {usable_cores()} usable here)")


def resolve_threads(requested: int, processes: int | None = None) -> int:
    """``--num_threads``: a count as given, 0 the :func:`auto_threads` rule."""
    check_threads(requested)
    return requested or auto_threads(processes)


#: The thread count a run directory's first session chose with ``--num_threads=0``.
RUN_THREADS = "threads.json"


def run_threads(run_dir: str | Path, requested: int, resuming: bool) -> int:
    """:func:`resolve_threads` for a run that can resume: with ``--num_threads=0`` the first
    session's count (kept in ``run_dir/threads.json``) is used again on resume, so a resumed
    run sums in the same order and ends bit for bit where an uninterrupted one would have,
    whatever else the machine runs by then. A count given explicitly is used as given."""
    path = Path(run_dir) / RUN_THREADS
    if requested == 0 and resuming:
        try:
            kept = json.loads(path.read_text()).get("threads")
        except (OSError, ValueError, AttributeError):
            kept = None
        if isinstance(kept, int) and not isinstance(kept, bool) and 1 <= kept <= max_threads():
            return kept
    threads = resolve_threads(requested)
    if requested == 0:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps({"threads": threads}) + "\n")
        os.replace(tmp, path)
    return threads

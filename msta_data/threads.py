"""How many CPU threads a process should compute with, when the user does not say.

torch (and OpenMP under it) takes every core by default. On a machine another job already
keeps busy, its threads then wait on each other: msta-train ran 30x slower with the default
than with one thread. :func:`auto_threads` gives each process the cores nobody else is using,
shared among the processes of the run:

    threads = max(1, (cores - busy) // processes)

``cores`` are the cores this process may run on (its CPU affinity, so a container's or
``taskset``'s limit counts), ``busy`` the other work running now: the tasks the kernel counts
as runnable (``/proc/loadavg``) less this process's own running threads, the median of a few
looks over ~0.1 s, rounded to the nearest whole core (the load average is not used: it still
counts a job that ended a minute ago, this command's own previous runs included), and
``processes`` the run's processes on this machine (torchrun's ``LOCAL_WORLD_SIZE``; 1
otherwise). Where /proc is missing, the 1-minute load average stands in. Every
``--num_threads`` option takes 0 for this rule (the default) or a count. ``make
bench-threads`` measures the rule against fixed counts on an idle and a loaded machine.
"""

from __future__ import annotations

import os
import statistics
import time
from pathlib import Path

#: The kernel's load figures: 1-, 5-, 15-minute averages, then "runnable/total" tasks.
LOADAVG = Path("/proc/loadavg")


def usable_cores() -> int:
    """The cores this process may run on (its affinity where the OS has one)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def _runnable(loadavg: str) -> int:
    """The runnable tasks of a /proc/loadavg text (its fourth field, ``runnable/total``)."""
    fields = loadavg.split()
    return int(fields[3].split("/")[0]) if len(fields) > 3 else 0


def _own_running() -> int:
    """This process's threads in the running state (/proc/self/task/*/stat)."""
    n = 0
    for stat in Path("/proc/self/task").glob("*/stat"):
        try:
            n += stat.read_text().rsplit(")", 1)[1].split()[0] == "R"
        except (OSError, IndexError):
            continue
    return n


def busy_cores(samples: int = 5, interval_s: float = 0.02) -> float:
    """Cores other work keeps busy now (module docstring): the median over ``samples``
    looks of the runnable tasks less this process's running threads."""
    try:
        looks = []
        for i in range(samples):
            if i:
                time.sleep(interval_s)
            looks.append(max(0, _runnable(LOADAVG.read_text()) - _own_running()))
        return float(statistics.median(looks))
    except (OSError, ValueError):
        return float(os.getloadavg()[0]) if hasattr(os, "getloadavg") else 0.0


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

"""Rollouts on Ray: worker processes run blocks of episodes, the caller commits the results.

``--workers=N`` (msta-collect, msta-correct, msta-finetune, msta-eval) runs the episodes on
N Ray actors of one CPU each, on a local Ray started for the run (``num_cpus=N``) or on an
existing cluster (``--ray_address``). Nothing here imports Ray until a pool is made, so the
single-process commands (``--workers=0``, the default) never load it.

The unit of work is a *block*: a fixed set of episode slots (or evaluation trials) that one
worker simulates and labels together, in one batched simulator. Blocks are planned from the
run's settings alone (:func:`plan_blocks`), never from the worker count, and every slot draws
its randomness from its own stream keyed by (run seed, slot index), so what a block returns
does not depend on which worker ran it or on how many there are. :class:`RayPool` hands the
results to the caller in block order (one committer: the process that writes the dataset).

A worker that dies (killed, out of memory, its node lost) is replaced and its block run again
from the start on a fresh worker; the caller only ever sees whole blocks, so nothing
half-simulated reaches a dataset. A block that kills :data:`MAX_TRIES` workers in a row ends
the run with an error naming it.
"""

from __future__ import annotations

import logging
import math
import os
import socket
import sys
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, Self

import numpy as np

#: Workers a block may kill before the run gives up on it.
MAX_TRIES = 3
#: Blocks finished ahead of the next one to commit, per worker (bounds the driver's memory).
AHEAD_PER_WORKER = 2
#: Test hook: ``"<block>:<flag file>"`` makes the worker running that block exit hard
#: (``os._exit``) in the middle of its rollout, once (the first to create the flag file).
EXIT_HOOK = "MSTA_TEST_WORKER_EXIT"


@dataclass
class RayOptions:
    """Args:
        workers: Ray workers that run the rollouts (simulate, act, label; one CPU each)
            while this process commits their results, in order. 0 = the single-process
            path without Ray. Results are the same for any number >= 1 (docs/scale.md).
        ray_address: the Ray cluster the workers run on (``auto``, ``HOST:6379``,
            ``ray://HOST:10001``); empty = a local Ray started for the run with ``workers``
            CPUs. Needs ``workers`` >= 1.
    """

    workers: int = 0
    ray_address: str = ""


#: The most Ray workers a command asks for (each is a process with its own simulator).
MAX_WORKERS = 4096


#: Ray's logger of the "token authentication is enabled" warning (every local start).
_RAY_TOKEN_LOGGER = "ray._private.authentication.authentication_token_setup"


def check_ray_options(workers: int, ray_address: str) -> None:
    """One-line errors for bad ``--workers`` / ``--ray_address`` values."""
    if (isinstance(workers, bool) or not isinstance(workers, int)
            or not 0 <= workers <= MAX_WORKERS):
        raise ValueError(f"workers={workers!r} must be an integer in [0, {MAX_WORKERS}] "
                         "(0 = no Ray; one CPU each)")
    if ray_address and not workers:
        raise ValueError(f"ray_address={ray_address!r} needs --workers >= 1")


def check_reachable(address: str, timeout: float = 5.0) -> None:
    """A one-line error for a ``HOST:PORT`` (or ``ray://HOST:PORT``) address where nothing
    listens, instead of Ray's minutes of connection retries; ``auto`` and empty pass."""
    hostport = address.removeprefix("ray://")
    host, sep, port = hostport.rpartition(":")
    if not address or address == "auto" or not sep or not port.isdigit():
        return
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as e:
        raise ValueError(f"ray_address={address!r}: no Ray cluster answers there ({e}); "
                         "start one with `ray start --head` or pass its address") from None


class Job(Protocol):
    """What a pool runs: picklable (Ray ships it to every worker once per job)."""

    def setup(self) -> Any:
        """Per-worker state built once per job (a simulator, a teacher)."""

    def run(self, state: Any, block: Any) -> Any:
        """One block's result (picklable; numpy arrays travel without copies)."""


def plan_blocks(total: int, size: int) -> list[np.ndarray]:
    """Slots ``0..total-1`` in ``ceil(total / size)`` consecutive blocks of equal size (the
    last one smaller when ``total`` does not divide): block b holds the same slots whatever
    the worker count, so the run's results do not depend on it.

    Args:
        total: slots (episodes or trials) in the run.
        size: most slots per block (the simulator's batch, ``--num_envs``).
    """
    if total <= 0:
        return []
    n = math.ceil(total / size)
    per = math.ceil(total / n)
    return [np.arange(b * per, min((b + 1) * per, total)) for b in range(n)]


def block_seed(seed: int, block: int) -> int:
    """A 32-bit seed for the per-block generators (action noise, DAgger coin flips, test-time
    masks), a function of (run seed, block index) only."""
    return int(np.random.SeedSequence([int(seed), int(block)]).generate_state(1)[0])


def exit_if_asked(block: int) -> None:
    """The :data:`EXIT_HOOK` test hook, called by a worker in the middle of a rollout."""
    spec = os.environ.get(EXIT_HOOK, "")
    if not spec or int(spec.split(":", 1)[0]) != block:
        return
    try:
        fd = os.open(Path(spec.split(":", 1)[1]), os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        return
    os.close(fd)
    os._exit(17)


#: This worker process's simulators by settings (:func:`cached`), the latest last.
_CACHE: dict[str, Any] = {}


def cached(key: str, build: Callable[[], Any], keep: int = 4) -> Any:
    """The object ``build()`` made for ``key`` in this process, made once: a worker reuses a
    simulator across jobs with the same settings (a stage-2 round, an evaluation run), as one
    process reuses its own; the ``keep`` most recently used stay."""
    obj = _CACHE.pop(key) if key in _CACHE else build()
    _CACHE[key] = obj
    while len(_CACHE) > keep:
        _CACHE.pop(next(iter(_CACHE)))
    return obj


class _Worker:
    """The Ray actor: caches one job's deserialized object and state across its blocks."""

    def __init__(self, threads: int, exit_hook: str) -> None:
        if exit_hook:  # the test hook travels with the worker, not with Ray's environment
            os.environ[EXIT_HOOK] = exit_hook
        self.threads, self.key, self.job, self.state = threads, None, None, None

    def run(self, job_ref: list, block: Any) -> Any:
        import ray  # lazy: Ray (~0.7 s) loads only with --workers or a Ray address

        key = job_ref[0].hex()
        if key != self.key:  # a new job: fetch it once, build its state once
            self.job, self.state, self.key = ray.get(job_ref[0]), None, None
            if "torch" in sys.modules:  # the job's policies compute on this worker's CPUs
                sys.modules["torch"].set_num_threads(self.threads)
            self.state, self.key = self.job.setup(), key
        return self.job.run(self.state, block)


def _lost_errors() -> tuple[type[BaseException], ...]:
    """Ray's errors that mean "the worker (or its node) is gone", not "the block failed"."""
    from ray import exceptions as E  # lazy: Ray (~0.7 s) loads only with --workers or a Ray address

    return (E.RayActorError, E.WorkerCrashedError, E.NodeDiedError, E.ObjectLostError)


class RayPool:
    """``workers`` Ray actors (one CPU each) that run the blocks of jobs.

    Args:
        workers: actors to start.
        address: an existing cluster's address; empty = a local Ray with ``workers`` CPUs,
            started here unless this process is already connected to one.
        threads: torch threads per worker.
    """

    def __init__(self, workers: int, address: str = "", threads: int = 1) -> None:
        import ray  # lazy: Ray (~0.7 s) loads only with --workers or a Ray address

        t0 = time.monotonic()
        check_ray_options(workers, address)
        if workers < 1:
            raise ValueError("a RayPool needs workers >= 1")
        self.started = not ray.is_initialized()
        if self.started:
            check_reachable(address)
            # a local Ray keeps its default token authentication without the line saying so
            logging.getLogger(_RAY_TOKEN_LOGGER).setLevel(logging.ERROR)
            kw: dict[str, Any] = {"address": address} if address else {"num_cpus": workers}
            ray.init(include_dashboard=False, log_to_driver=False, logging_level="warning",
                     **kw)
        self.workers, self.threads = workers, threads
        self._cls = ray.remote(num_cpus=1)(_Worker)
        self.actors = [self._new() for _ in range(workers)]
        self.replaced = 0  # workers lost and replaced so far
        ray.get([a.__ray_ready__.remote() for a in self.actors])
        self.startup_s = time.monotonic() - t0
        where = f"on {address}" if address else (
            "on a local Ray started for this run" if self.started else "on this process's Ray")
        print(f"Ray: {workers} workers ready in {self.startup_s:.1f} s {where}",
              file=sys.stderr, flush=True)

    def _new(self) -> Any:
        return self._cls.remote(self.threads, os.environ.get(EXIT_HOOK, ""))

    def map(self, job: Job, blocks: Sequence[Any], on_result: Callable[[int, Any], None]
            ) -> None:
        """Run ``job`` on every block; call ``on_result(i, result)`` in block order, in this
        process, as soon as blocks 0..i are all done. A lost worker is replaced and its block
        run again; an exception raised by a block (or by ``on_result``) ends the run, with
        the workers still busy replaced so the pool stays usable."""
        import ray  # lazy: Ray (~0.7 s) loads only with --workers or a Ray address

        ref = [ray.put(job)]
        todo, running = deque(range(len(blocks))), {}
        done: dict[int, Any] = {}
        tries = [0] * len(blocks)
        idle, nxt = list(range(len(self.actors))), 0
        try:
            while nxt < len(blocks):
                while idle and todo and todo[0] < nxt + AHEAD_PER_WORKER * self.workers:
                    a, i = idle.pop(), todo.popleft()
                    running[self.actors[a].run.remote(ref, blocks[i])] = (i, a)
                ready, _ = ray.wait(list(running), num_returns=1)
                i, a = running.pop(ready[0])
                try:
                    done[i] = ray.get(ready[0])
                except ray.exceptions.RayTaskError as e:  # the block raised: the caller's error
                    raise (e.cause if isinstance(e.cause, Exception) else e) from e
                except _lost_errors() as e:
                    tries[i] += 1
                    if tries[i] >= MAX_TRIES:
                        raise RuntimeError(f"block {i} lost {tries[i]} workers in a row; last: "
                                           f"{type(e).__name__}") from None
                    self._replace(a)
                    todo.appendleft(i)
                idle.append(a)
                while nxt in done:
                    on_result(nxt, done.pop(nxt))
                    nxt += 1
        finally:
            for _, a in running.values():  # abandoned work: those workers start afresh
                self._replace(a)

    def _replace(self, a: int) -> None:
        import ray  # lazy: Ray (~0.7 s) loads only with --workers or a Ray address

        ray.kill(self.actors[a], no_restart=True)
        self.actors[a] = self._new()
        self.replaced += 1

    def close(self) -> None:
        """Stop the workers, and the local Ray if this pool started it."""
        import ray  # lazy: Ray (~0.7 s) loads only with --workers or a Ray address

        for actor in self.actors:
            ray.kill(actor, no_restart=True)
        self.actors = []
        if self.started and ray.is_initialized():
            ray.shutdown()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: One pool per (workers, address), kept across the rounds and runs of a process.
_SHARED: dict[tuple[int, str], RayPool] = {}


def shared_pool(workers: int, address: str = "") -> RayPool:
    """The process's pool of ``workers`` workers on ``address``, started on first use and
    kept for later rounds and evaluation runs (a stage-2 run asks once per round); it ends
    with the process, or :func:`close_shared`."""
    import ray  # lazy: Ray (~0.7 s) loads only with --workers or a Ray address

    key = (workers, address)
    pool = _SHARED.get(key)
    if pool is not None and (not ray.is_initialized() or not pool.actors):
        del _SHARED[key]  # its Ray was shut down
        pool = None
    if pool is None:
        # the other pools go unless the cluster has a CPU for every worker of them all (an
        # actor waiting for a CPU would wait for ever)
        cpus = ray.cluster_resources().get("CPU", 0) if ray.is_initialized() else 0
        if workers + sum(k[0] for k in _SHARED) > cpus:
            close_shared()
        pool = _SHARED[key] = RayPool(workers, address)
    return pool


def close_shared() -> None:
    """Close every shared pool (tests; a process's end does it too)."""
    while _SHARED:
        _SHARED.popitem()[1].close()

"""Training on several processes: ``torchrun --nproc_per_node=N msta-train ...``.

Under ``torchrun`` (``RANK``, ``WORLD_SIZE`` and ``LOCAL_RANK`` in the environment) a command
that trains (msta-train, msta-correct, msta-finetune, msta-compare) runs as one job of N
processes, and a plain process (no such variables) runs exactly as before:

- **rank 0 runs the command** as a single process would: it reads and writes the dataset,
  rolls out, evaluates, and alone writes checkpoints, metrics, progress files and the final
  policy;
- **the other ranks train with it**: at each training loop (:func:`msta.train.loop.fit`) rank 0
  sends them a :class:`FitJob` (the student, the dataset's recipe, the loop settings), all
  ranks train it together under DistributedDataParallel (gloo on the CPU, NCCL on CUDA), and
  the others wait for the next one until rank 0's command ends (:func:`msta.train.loop.rank0_runs`).

**The global batch does not depend on N.** Every rank draws the same batch of window indices
from the seeded sampler (``--batch_size`` windows) and trains on its share, rows
``r * B/N .. (r+1) * B/N``; DDP averages the gradients, and the loss is a mean over samples,
so a step is the single process's step on the same ``B`` windows. The random token removal
is drawn for the whole global batch too (:class:`ShardedDraws`): every draw from the mask
generator is made at the global batch's size and each rank keeps its rows, so every window
gets the mask it gets in one process and the generators of all ranks stay in step.

What stays the same for any N, to float rounding (sums in another order): the weights after
every step, the sampler and mask streams, checkpoints, resume. What does not: dropout
(``--policy.dropout``, 0 in every preset) draws from each rank's own global RNG; the logged
training loss is the mean of the ranks' shard losses (equal to the global mean in exact
arithmetic); validation runs on rank 0 alone.

Resume: rank 0 writes ``checkpoints/``; on ``--resume=true`` every rank restores the same
checkpoint, so a multi-node job needs the run directory and the dataset on a shared
filesystem.
"""

from __future__ import annotations

import copy
import gc
import math
import os
import sys
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
from torch import nn
from torch.distributed.distributed_c10d import _set_pg_timeout
from torch.overrides import TorchFunctionMode

from msta.data.windows import WindowDataset

#: How long the other ranks wait for rank 0's next training loop (its rollouts and
#: evaluations in between may take hours).
JOB_WAIT = timedelta(days=7)
#: How long a rank waits for the others to join (torchrun starts them together; variables
#: left over in a shell would otherwise wait for ranks that never come).
#: ``MSTA_DDP_JOIN_TIMEOUT_S`` overrides it (a multi-node job whose nodes start apart).
JOIN_WAIT_S = 300.0


#: The variables torchrun sets that this module reads (named in messages).
ENV_NAMES = ("RANK", "WORLD_SIZE", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT")


@dataclass(frozen=True)
class Launch:
    """This process's place in a torchrun job (from ``RANK``, ``WORLD_SIZE``,
    ``LOCAL_RANK``)."""

    rank: int
    world: int
    local_rank: int


def join_wait_s() -> float:
    """Seconds a rank waits for the job to form (:data:`JOIN_WAIT_S`, or the environment's
    ``MSTA_DDP_JOIN_TIMEOUT_S``)."""
    text = os.environ.get("MSTA_DDP_JOIN_TIMEOUT_S", "")
    try:
        wait = float(text) if text else JOIN_WAIT_S
    except ValueError:
        wait = math.nan
    if not 0 < wait <= JOB_WAIT.total_seconds():
        raise ValueError(f"MSTA_DDP_JOIN_TIMEOUT_S={text!r} must be seconds in (0, "
                         f"{JOB_WAIT.total_seconds():g}]")
    return wait


def launched() -> Launch | None:
    """The torchrun variables of this process, or None for a plain process.

    Raises:
        ValueError: some of the variables are set but not all, or they are not integers.
    """
    names = ENV_NAMES[:3]
    given = {n: os.environ.get(n) for n in names}
    if not any(given.values()):
        return None
    try:
        rank, world, local = (int(given[n] or "") for n in names)
    except ValueError:
        raise ValueError(f"torchrun variables {given}: RANK, WORLD_SIZE and LOCAL_RANK must all "
                         "be integers (launch with torchrun, or unset them)") from None
    if not 0 <= rank < world or local < 0:
        raise ValueError(f"torchrun variables {given}: need 0 <= RANK < WORLD_SIZE")
    return Launch(rank, world, local)


def check_batch(batch_size: int, world: int) -> None:
    """The global batch must split evenly over the ranks."""
    if batch_size % world:
        raise ValueError(f"batch_size={batch_size} does not split over {world} processes; give "
                         f"a multiple of {world} (the global batch is the same for any number "
                         "of processes: each trains batch_size / N of it)")


class ShardedDraws(TorchFunctionMode):
    """Random draws from ``generator`` made for the whole global batch; this rank keeps its
    rows.

    A student draws its token-removal scores (and dummy tokens) as ``(B, ...)`` tensors from
    the mask generator; inside this mode a draw of ``B = local`` rows is made at
    ``local * world`` rows and rows ``rank * local ..`` are returned, which are the values the
    single process draws for those windows. Any other use of the generator is refused.

    Args:
        generator: the loop's mask generator.
        rank, world: this process and the job's size.
        local: windows per rank.
    """

    DRAWS = (torch.rand, torch.randn, torch.randint)

    def __init__(self, generator: torch.Generator, rank: int, world: int, local: int) -> None:
        super().__init__()
        self.generator, self.rank, self.world, self.local = generator, rank, world, local

    def __torch_function__(self, func: Any, types: Any, args: tuple = (),
                           kwargs: dict | None = None) -> Any:
        kwargs = dict(kwargs or {})
        if kwargs.get("generator") is not self.generator:
            return func(*args, **kwargs)
        if func not in self.DRAWS:
            raise RuntimeError(f"{getattr(func, '__name__', func)} from the mask generator: only "
                               "(batch, ...) draws with rand, randn and randint can be sharded "
                               "over processes")
        if func is torch.randint:
            lead, size = (args[:-1], args[-1]) if "size" not in kwargs else (args, kwargs["size"])
            kwargs.pop("size", None)
        else:
            lead = ()
            size = kwargs.pop("size", args[0] if len(args) == 1 and not isinstance(args[0], int)
                              else args)
        size = tuple(size)
        if not size or size[0] != self.local:
            raise RuntimeError(f"a draw of shape {size} from the mask generator is not one row per "
                               f"window of this rank's {self.local}; it cannot be sharded")
        full = func(*lead, (self.local * self.world, *size[1:]), **kwargs)
        return full[self.rank * self.local:(self.rank + 1) * self.local]


class _Loss(nn.Module):
    """``policy.loss`` as a module's forward, for DDP, with the draws sharded."""

    def __init__(self, policy: nn.Module, world: int, rank: int, local: int) -> None:
        super().__init__()
        self.policy, self.world, self.rank, self.local = policy, world, rank, local

    def forward(self, *args: Any) -> Any:
        """``policy.loss(*args)`` as ``train_step`` calls it (the generator is the fourth)."""
        with ShardedDraws(args[3], self.rank, self.world, self.local):
            return self.policy.loss(*args)


@dataclass
class WindowRecipe:
    """How the other ranks load rank 0's ``WindowDataset`` (from the same files)."""

    root: Path
    sensors: tuple[str, ...]
    T: int
    extra_columns: tuple[str, ...]
    episodes: list[int]
    fps: int

    def load(self) -> WindowDataset:
        return WindowDataset(self.root, self.sensors, self.T, self.extra_columns, self.episodes,
                             fps=self.fps, verify="sizes")  # rank 0 verified the checksums


@dataclass
class FitJob:
    """One training loop, as rank 0 sends it to the other ranks.

    Args:
        policy: the student before the loop (a CPU copy; DDP copies rank 0's weights anyway).
        device: rank 0's device type (``cpu``/``cuda``): each rank uses its own device of it.
        dataset: a :class:`WindowRecipe`, or the dataset object itself.
        cfg: the loop's settings (a ``LoopConfig``).
        out: the run directory (read on resume, never written by these ranks).
        resume: restore ``out/checkpoints/last``.
        weights: per-window sampling weights, or None.
        sync_stop: rank 0 has a deadline: every step the ranks agree whether to stop.
        threads: rank 0's torch threads.
    """

    policy: nn.Module
    device: str
    dataset: Any
    cfg: Any
    out: Path
    resume: bool
    weights: np.ndarray | None
    sync_stop: bool
    threads: int

    @classmethod
    def of(cls, policy: nn.Module, dataset: Any, cfg: Any, out: Path, resume: bool,
           weights: np.ndarray | None, sync_stop: bool) -> FitJob:
        device = next(policy.parameters()).device
        cpu = policy if device.type == "cpu" else copy.deepcopy(policy).to("cpu")
        if isinstance(dataset, WindowDataset):
            dataset = WindowRecipe(dataset.root, dataset.sensors, dataset.T,
                                   dataset.extra_columns, list(dataset.episodes), dataset.fps)
        return cls(cpu, device.type, dataset, cfg, out, resume, weights, sync_stop,
                   torch.get_num_threads())


class Group:
    """The job's process group: sharding, the DDP wrapper, the job channel.

    Args:
        where: this process's place (:func:`launched`).
    """

    def __init__(self, where: Launch) -> None:
        self.rank, self.world, self.local_rank = where.rank, where.world, where.local_rank
        cuda = torch.cuda.is_available()
        if cuda:
            torch.cuda.set_device(where.local_rank)
        # one group, CPU tensors on gloo, CUDA tensors on NCCL; the long timeout is for the
        # other ranks' wait while rank 0 rolls out or evaluates between training loops (a
        # second group for that wait breaks torchrun's restarts); a rank that dies ends the
        # job at once anyway (torchrun stops the others)
        wait = join_wait_s()
        names = " ".join(f"{n}={os.environ.get(n, '')}" for n in ENV_NAMES)
        if where.rank == 0:
            print(f"torchrun job of {where.world} processes ({names}): waiting up to "
                  f"{wait:g} s for the other ranks", file=sys.stderr, flush=True)
        try:
            dist.init_process_group("cpu:gloo,cuda:nccl" if cuda else "gloo", rank=where.rank,
                                    world_size=where.world, timeout=timedelta(seconds=wait))
        except (RuntimeError, dist.DistError) as e:
            raise ValueError(
                f"the torchrun job did not form within {wait:g} s ({names}; "
                f"{' '.join(str(e).split())[:120]}): variables left from another job? unset "
                "them to train in one process, or set MSTA_DDP_JOIN_TIMEOUT_S") from None
        _set_pg_timeout(JOB_WAIT)  # formed: the long wait between training loops

    @property
    def main(self) -> bool:
        return self.rank == 0

    def device(self, kind: str) -> torch.device:
        """This rank's device of ``kind`` (its own GPU: ``cuda:LOCAL_RANK``)."""
        return torch.device("cuda", self.local_rank) if kind == "cuda" else torch.device(kind)

    def shard(self, rows: np.ndarray) -> np.ndarray:
        """This rank's share of the global batch's window indices."""
        n = len(rows) // self.world
        return rows[self.rank * n:(self.rank + 1) * n]

    def wrap(self, policy: nn.Module, batch_size: int) -> nn.Module:
        """``policy.loss`` under DDP (called as ``train_step``'s ``loss_fn``)."""
        check_batch(batch_size, self.world)
        dev = next(policy.parameters()).device
        return nn.parallel.DistributedDataParallel(
            _Loss(policy, self.world, self.rank, batch_size // self.world),
            device_ids=[dev.index] if dev.type == "cuda" else None,
            find_unused_parameters=True)  # a student may leave a parameter out of its loss

    def mean(self, values: dict[str, float]) -> dict[str, float]:
        """The ranks' mean of each value."""
        t = torch.tensor(list(values.values()), dtype=torch.float64)
        dist.all_reduce(t)
        return dict(zip(values, (t / self.world).tolist(), strict=True))

    def any(self, flag: bool) -> bool:
        """True on every rank when it is True on one."""
        t = torch.tensor([int(flag)])
        dist.all_reduce(t, op=dist.ReduceOp.MAX)
        return bool(t.item())

    def send(self, job: FitJob | None) -> None:
        """Rank 0: the next training loop (None: the command is over)."""
        dist.broadcast_object_list([job], src=0)

    def receive(self) -> FitJob | None:
        """The other ranks: wait for rank 0's next training loop."""
        box: list[Any] = [None]
        dist.broadcast_object_list(box, src=0)
        return box[0]

    def close(self) -> None:
        """Every rank leaves together (one leaving early breaks the others' connections)."""
        gc.collect()  # the last loop's DDP reducer goes before its process group
        dist.barrier()
        dist.destroy_process_group()


_GROUP: Group | None = None


def current() -> Group | None:
    """The job's group while :func:`msta.train.loop.rank0_runs` runs a command under torchrun,
    else None."""
    return _GROUP


def join(where: Launch, batch_size: int) -> Group:
    """Join the job (its batch checked to split first); :func:`current` returns it until
    :func:`leave`."""
    global _GROUP
    if batch_size % where.world and where.rank:
        raise SystemExit(2)  # rank 0 says why
    check_batch(batch_size, where.world)
    _GROUP = Group(where)
    return _GROUP


def leave() -> None:
    """Leave the job together with the other ranks."""
    global _GROUP
    if _GROUP is not None:
        _GROUP.close()
    _GROUP = None

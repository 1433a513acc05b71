"""A torchrun worker for tests/train/test_ddp.py: msta-train whose rank 0 kills itself
(SIGKILL, no cleanup) after step ``KILL_AT``; torchrun then stops the other ranks.

    python -m torch.distributed.run --standalone --nproc_per_node=2 \\
        tests/train/ddp_kill_worker.py KILL_AT <msta-train flags>
"""

from __future__ import annotations

import os
import signal
import sys

from msta.train.cli import parse_cli
from msta.train.loop import rank0_runs
from msta.train.stage1 import train
from msta.train.train_config import TrainConfig


def main() -> None:
    kill_at, argv = int(sys.argv[1]), sys.argv[2:]
    cfg = parse_cli(TrainConfig, argv, prog="ddp_kill_worker")

    def on_step(step: int, metrics: dict[str, float]) -> None:
        if step == kill_at:
            os.kill(os.getpid(), signal.SIGKILL)

    rank0_runs(lambda: train(cfg, on_step=on_step), cfg.batch_size)


if __name__ == "__main__":
    main()

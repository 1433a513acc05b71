"""A torchrun worker for tests/train/test_ddp.py: the job forms within
``MSTA_DDP_JOIN_TIMEOUT_S``, then rank 0 works longer than that before its next message;
the other rank must still be waiting (the long wait between training loops).

    MSTA_DDP_JOIN_TIMEOUT_S=2 python -m torch.distributed.run --standalone \\
        --nproc_per_node=2 tests/train/ddp_slow_rank0.py
"""

from __future__ import annotations

import time

from msta.train.ddp import join, launched, leave


def main() -> None:
    group = join(launched(), batch_size=2)
    if group.main:
        time.sleep(5)  # a rollout between training loops, longer than the join's limit
        group.send(None)
    else:
        assert group.receive() is None
    leave()
    print(f"rank {group.rank}: done")


if __name__ == "__main__":
    main()

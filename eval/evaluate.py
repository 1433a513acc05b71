"""``msta-eval``: the paper's experiments on any checkpoints, as one command.

    msta-eval --policies teacher,CKPT_A,user/ckpt_b@v1 --suite quick --output_dir outputs/eval
    msta-eval --policies teacher,CKPT --suite paper --trials 500 --terrains stairs_up,discrete
    msta-eval --policies teacher,A,B,C,D --scenarios mask_matrix --matrix A=0.75:0.5,B=0.5:0.5,...
    msta-eval --policies teacher,CKPT --scenarios sensor_faults --faults stuck:0:encoder:2

``--policies`` entries: ``teacher`` (the reference teacher of ``--teacher.type``, rolled out
again as a row), ``teacher:<type>`` (another registered teacher as a fixed-input row, e.g.
``teacher:zero`` holds the default pose), a checkpoint directory, or a hub id
``user/name[@revision]`` (pulled by msta's one path-or-hub rule, ``msta.data.locate``).

Writes into ``--output_dir``: ``metrics.json`` (every number with its trial count and 95 %
interval per cell, the configuration, each policy's source and revision), ``report.md``
(Table I layout and one table per scenario, trials per cell, intervals, a warning for a
student whose figures do not change with its inputs), PNG plots for scenarios 2-5,
``timing.json``, and optionally a video (``--video``). See docs/eval.md for the metric
definitions; the runs themselves are :class:`msta.eval.evaluator.Evaluator`'s.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

from msta.data.budget import TimeLimitReached, stop
from msta.data.cli import parse_config
from msta.data.errors import DirectoryLockedError
from msta.eval import report
from msta.eval.eval_config import EvalConfig


def main(argv: list[str] | None = None) -> None:
    """Console entry point (``msta-eval``)."""
    # deterministic cuBLAS (students on CUDA): only read before CUDA's first matrix product
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    cfg = parse_config(EvalConfig, argv, "msta-eval")  # bad flags: one line, exit 2
    started = time.time()
    from msta.eval.evaluation import evaluate  # lazy: torch after parsing (--help at once)

    try:
        metrics = evaluate(cfg)
    except TimeLimitReached as e:
        stop("msta-eval", e, "the same command with --resume=true")
    except (KeyError, ValueError, FileNotFoundError, NotADirectoryError,
            DirectoryLockedError) as e:
        msg = e.args[0] if isinstance(e, KeyError) and e.args else e
        print(f"msta-eval: error: {msg}", file=sys.stderr)
        raise SystemExit(2) from None
    out = Path(cfg.output_dir)
    print(report.table_one(metrics, "total"))
    plots = sorted(p.name for p in out.glob("*.png") if p.stat().st_mtime >= started - 1)
    print(f"\nmsta-eval: wrote {out / 'metrics.json'}, {out / 'report.md'}"
          + (f" and the plots {', '.join(plots)} in {out}/" if plots else
             " (no plots: they draw the sensor_removal, dead_joints, history, dummy_tokens and "
             "mask_matrix scenarios)"))


if __name__ == "__main__":
    main()

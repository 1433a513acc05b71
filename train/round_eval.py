"""``msta-correct``'s per-round evaluation: msta-eval's figures for each round's checkpoint.

A round's checkpoint runs msta-eval's ``token_removal`` conditions at ``--eval.mask_ratios``
through :class:`msta.eval.evaluator.Evaluator` on the trials of ``--eval.*``
(:class:`msta.eval.scenarios.TrialConfig`, msta-eval's own options), against the reference
teacher on the same trials. The records stored in progress.json are msta-eval's run
records (``raw``, ``normalized``, trials and 95 % intervals per cell), so msta-correct's
table (:func:`print_table`), the model card (``msta.train.push.round_eval``) and
``msta-eval --policies teacher,<round_r> --scenarios token_removal`` with the same options
on the same device type report the same figures.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from msta.eval.evaluator import Evaluator, student_entry
from msta.eval.scenarios import ScenarioContext, TrialConfig, get_scenario
from msta.eval.trial_env import torch_eval_settings
from msta.policies.teacher.config import TeacherConfig


@dataclass
class RoundEvalConfig(TrialConfig):
    """The per-round evaluation: msta-eval's ``token_removal`` conditions at ``mask_ratios``
    on msta-eval's trials (``msta.eval.evaluator.Evaluator``: the same trial layout, per-trial
    random streams, metrics, normalization by the teacher and 95-percent intervals). Round r's
    figures are those of ``msta-eval --policies teacher,OUTPUT_DIR/round_<r>
    --scenarios token_removal`` with the same suite, trials, terrains, levels, episode_length_s,
    seed and device type; the model card shows them too. The defaults (the quick suite: 5 trials, one 3 s
    episode per paper terrain at level 1) keep a round's evaluation to a few seconds of
    simulation; raise --eval.trials (and --eval.levels) for tighter intervals.
    """

    enabled: bool = True
    """evaluate the starting checkpoint (round 0) and every round (false: no per-round table
    and no figures on the model card)."""
    mask_ratios: tuple[float, ...] = (0.0, 0.5)
    """test-time token-removal ratios evaluated for the student (0.5 = msta-eval's
    "mask 50" condition)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        self.mask_ratios = tuple(float(m) for m in self.mask_ratios)
        if not self.mask_ratios or not all(0.0 <= m < 1.0 for m in self.mask_ratios):
            raise ValueError(f"eval.mask_ratios={self.mask_ratios} must be values in [0, 1)")


class RoundEvaluator:
    """Phase 5 of msta-correct through msta-eval's :class:`~msta.eval.evaluator.Evaluator` on
    ``cfg``'s trials. The reference teacher runs once per process, on first use; a
    checkpoint is evaluated from its directory, loaded as msta-eval loads it.

    Args:
        cfg: ``--eval.*``: which trials and test masks.
        teacher: the reference teacher (msta-correct's labelling teacher).
        device: where the students run (msta-correct's training device, which msta-eval's
            default ``--device=auto`` also picks: the same figures in both).
    """

    def __init__(self, cfg: RoundEvalConfig, teacher: TeacherConfig, device: str = "cpu") -> None:
        self.cfg, self.teacher_cfg, self.device = cfg, teacher, device
        self.cuda = torch.device(device).type == "cuda"
        self.ev: Any = None

    def teacher(self) -> dict[str, Any]:
        """The reference teacher's raw figures on the evaluation trials (msta.eval.metrics)."""
        if self.ev is None:
            ev = Evaluator(self.cfg, self.teacher_cfg, progress=False)
            with torch_eval_settings(self.cfg.num_threads, cuda=self.cuda):
                ev.run_reference()
            self.ev = ev
        return {"config": self.cfg.resolved(), **self.ev.reference}

    def student(self, ckpt: Path) -> dict[str, Any]:
        """msta-eval's run record (raw and normalized figures, intervals, trials) of the
        checkpoint ``ckpt`` per test mask, keyed ``f"{mask:g}"``."""
        self.teacher()
        entry = student_entry(ckpt, ckpt.name, str(ckpt), device=self.device)
        ctx = ScenarioContext(tuple(entry.obj.required_sensors), self.cfg.mask_ratios,
                              self.cfg.seed)
        with torch_eval_settings(self.cfg.num_threads, cuda=self.cuda):
            return {f"{c.value:g}": self.ev.condition(entry, c)
                    for c in get_scenario("token_removal").build(ctx)}



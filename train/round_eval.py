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

from dataclasses import replace
from pathlib import Path
from typing import Any

import torch

from msta.eval.evaluator import Evaluator, student_entry
from msta.eval.scenarios import ScenarioContext, get_scenario
from msta.eval.trial_env import torch_eval_settings
from msta.policies.teacher.config import TeacherConfig
from msta.train.correct_config import RoundEvalConfig


class RoundEvaluator:
    """Phase 5 of msta-correct through msta-eval's :class:`~msta.eval.evaluator.Evaluator` on
    ``cfg``'s trials. The reference teacher runs once per process, on first use; a
    checkpoint is evaluated from its directory, loaded as msta-eval loads it.

    Args:
        cfg: ``--eval.*``: which trials and test masks.
        teacher: the reference teacher (msta-correct's labelling teacher).
        device: where the students run (msta-correct's training device, which msta-eval's
            default ``--device=auto`` also picks: the same figures in both).
        robot: the robot the rounds simulate (``--env.robot``), simulated by the trials too;
            empty: ``cfg.robot`` (the A1 when that is empty).
    """

    def __init__(self, cfg: RoundEvalConfig, teacher: TeacherConfig, device: str = "cpu",
                 robot: str = "") -> None:
        #: the trials, on the rounds' robot
        self.cfg = replace(cfg, robot=robot) if robot and robot != cfg.robot else cfg
        self.teacher_cfg, self.device = teacher, device
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



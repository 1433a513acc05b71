"""``--push_to``: push training checkpoints to a Hugging Face–compatible hub with a model card.

``msta-train --push_to=user/name`` pushes ``output_dir/final`` with tag ``stage1``;
``msta-correct --push_to=user/name`` pushes ``output_dir/round_<r>`` with tag ``stage2-r<r>``
after the round's evaluation. The endpoint and token come from ``HF_ENDPOINT`` / ``HF_TOKEN``
(``msta.data.hub_push``); the token is never printed.

Tags are moved when they already exist (``move_tag=True``): a tag names the newest push of
that stage and round to the repo, and the commit sha (printed, and listed by
``msta-hub versions``) pins one exact version. Every push is one commit on ``main``, so
earlier versions stay in the history.

The model card records the training dataset (hub id and the commit sha it resolved to, or
for a local dataset the ``repo_id`` of its ``meta/msta.json``; local paths are never written:
:func:`msta.data.hub_cards.portable`), the training configuration, stage, round, summary metrics (stage 1:
the last train and validation losses of ``metrics.csv``; stage 2: msta-correct's per-round
figures, which are msta-eval's on the same trials: linear-velocity tracking and total
reward normalized by the teacher's, survival, their 95 % intervals and the trial count, at
each evaluated test mask) and, in stage 2, the per-terrain evaluation table and the
msta-eval command that reproduces it.

A failed push never touches the checkpoint on disk: :class:`PushError` names the directory
and how to retry: rerun with ``--resume=true`` (msta-train: a finished run is not trained
again, ``final/`` is pushed; msta-correct: finished rounds are skipped and the rounds not
yet pushed to ``--push_to`` are pushed).
"""

from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path
from typing import Any

import draccus

from msta.data import layout
from msta.data.hub_cards import CardInfo, portable
from msta.data.hub_eval import HEADLINE_FIGURES
from msta.data.hub_ids import parse_hub_id
from msta.data.hub_pull import resolve
from msta.data.hub_push import push
from msta.eval.metrics import headline

_SHA = re.compile(r"^[0-9a-f]{40}$")


class PushError(RuntimeError):
    """Pushing a saved checkpoint failed; the checkpoint is still on disk."""


def check_push_to(value: str) -> None:
    """Reject a ``--push_to`` that is not ``user/name`` (before any training starts).

    Args:
        value: the flag's value ("" = no push).
    """
    if not value:
        return
    try:
        hub_id = parse_hub_id(value, "model")
    except ValueError:
        hub_id = None  # raised below, outside the handler, so the message is the root cause
    if hub_id is None:
        raise ValueError(f"push_to={value!r}: expected a model repo id user/name")
    if hub_id.revision or value.startswith(("datasets/", "models/")):
        raise ValueError(f"push_to={value!r}: give only user/name (tags are set per stage and "
                         "round; no @revision or repo-type prefix)")


def dataset_source(spec: str, root: Path) -> dict[str, Any]:
    """Where the training data came from: ``{"repo", "revision", "path"}``.

    Args:
        spec: the ``--dataset`` value (a directory or a hub id).
        root: the local dataset root it resolved to (for a hub id: the pulled commit, whose
            directory name is the commit sha, or a copy of it).
    """
    if Path(spec).expanduser().is_dir():
        meta = root / layout.MSTA_META_PATH
        repo = json.loads(meta.read_text()).get("repo_id") if meta.is_file() else None
        return {"repo": repo or str(root), "revision": None, "path": str(root.resolve())}
    hub_id = parse_hub_id(spec, "dataset")
    rev = root.name if _SHA.match(root.name) else resolve(hub_id).revision
    return {"repo": hub_id.repo_id, "revision": rev, "path": None}


def push_checkpoint(ckpt: Path, repo_id: str, tag: str, card: Any, private: bool,
                    retry_hint: str) -> dict[str, str]:
    """Push ``ckpt`` as a commit on main of ``repo_id`` tagged ``tag``.

    Args:
        ckpt: the saved checkpoint directory.
        repo_id: ``user/name``.
        tag: moved to the new commit when it exists.
        card: a ``msta.data.hub_cards.CardInfo`` for README.md.
        private: create the repo as private.
        retry_hint: how to retry, for the error message.

    Returns:
        ``{"repo", "tag", "commit"}``.

    Raises:
        PushError: the push failed (``ckpt`` is untouched).
    """
    try:
        sha = push(ckpt, repo_id, tag=tag, private=private, card=card, move_tag=True,
                       message=f"{tag}: {ckpt.parent.name}/{ckpt.name}")
    except Exception as e:  # any client / HTTP failure: the checkpoint is safe on disk
        raise PushError(f"the checkpoint is saved at {ckpt}, but pushing it to {repo_id}@{tag} "
                        f"failed ({type(e).__name__}: {e}); {retry_hint}") from e
    print(f"pushed {ckpt} -> {repo_id}@{tag} (commit {sha[:12]})", flush=True)
    return {"repo": repo_id, "tag": tag, "commit": sha}


def _finite(d: dict[str, Any]) -> dict[str, float]:
    return {k: float(v) for k, v in d.items()
            if isinstance(v, (int, float)) and math.isfinite(float(v))}


def _card(src: dict[str, Any], config: dict[str, Any], stage: int, round_: int | None,
          metrics: dict[str, float], table: dict[str, dict[str, float]] | None,
          notes: str) -> CardInfo:
    """The card of a pushed checkpoint; local paths are left out (:func:`portable`)."""
    return CardInfo(dataset_repo=portable(src["repo"]), dataset_revision=src["revision"],
                    config=portable(config), stage=stage, round=round_,
                    metrics=metrics or None, eval_table=table, notes=notes.strip())


# ----- stage 1 -----------------------------------------------------------------------------
def stage1_metrics(out: Path) -> dict[str, float]:
    """The last train and validation values of ``out/metrics.csv`` (``train_*``, ``val_*``)."""
    metrics: dict[str, float] = {}
    path = out / "metrics.csv"
    if not path.is_file():
        return metrics
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            vals = {k: v for k, v in row.items() if v not in ("", None)}
            if "loss" in vals:
                metrics.update(step=float(vals["step"]), train_loss=float(vals["loss"]),
                               train_action_mse=float(vals["action_mse"]))
            metrics.update({k: float(v) for k, v in vals.items() if k.startswith("val_")})
    return _finite(metrics)


def push_stage1(cfg: Any, root: Path, out: Path, final: Path) -> dict[str, str]:
    """Push ``final`` (msta-train) with tag ``stage1``.

    Args:
        cfg: the ``TrainConfig``.
        root: the local dataset root training read.
        out: the run directory (metrics.csv).
        final: the saved final policy directory.
    """
    card = _card(dataset_source(cfg.dataset, root), draccus.encode(cfg), 1, None,
                 stage1_metrics(out), None, "Trained by `msta-train` (stage 1).")
    return push_checkpoint(final, cfg.push_to, "stage1", card, cfg.push_private,
                           "rerun the same command with --resume=true to push it (the "
                           "finished run is not trained again)")


# ----- stage 2 -----------------------------------------------------------------------------
def round_eval(prog: dict[str, Any], r: int) -> tuple[dict[str, float], dict | None]:
    """(metrics, per-terrain table) of round ``r`` from msta-correct's progress.json content.

    The figures are msta-eval's (msta-correct evaluates with ``msta.eval.evaluator.Evaluator``;
    :func:`msta.eval.metrics.headline` picks them, as for msta-correct's round table):
    per test mask m, ``lin_tracking_vs_teacher@mask<m>`` and ``total_vs_teacher@mask<m>``
    (per-step returns over the teacher's on the same trials), ``survival@mask<m>`` (share
    of trials without a fall), each with ``<name>_ci95_low@mask<m>`` / ``_high`` (95 %
    interval; absent with one trial), and ``eval_trials``; plus the round's train and
    validation losses and its episode count. Table rows are the terrains and ``average``;
    columns ``<name>@mask<m>`` and ``trials``.
    """
    rec = prog["rounds"][str(r)]
    tr = rec.get("train", {})
    metrics = {"train_loss": tr.get("train_loss"), "val_loss": tr.get("val_loss"),
               "episodes": rec.get("episodes_after")}
    table: dict[str, dict[str, float]] = {}
    for m, run in (rec.get("eval") or {}).items():
        if run.get("status") != "ok":
            continue
        cells = headline(run)
        avg = cells["average"]
        metrics["eval_trials"] = avg["trials"]
        for name, _, _ in HEADLINE_FIGURES:
            metrics[f"{name}@mask{m}"] = avg[name]
            if avg["ci"][name]:
                low, high = avg["ci"][name]
                metrics[f"{name}_ci95_low@mask{m}"] = low
                metrics[f"{name}_ci95_high@mask{m}"] = high
            for t, cell in cells.items():
                row = table.setdefault(t, {})
                row[f"{name}@mask{m}"] = cell[name]
                row["trials"] = cell["trials"]
    return _finite(metrics), ({k: _finite(v) for k, v in table.items()} or None)


def eval_note(prog: dict[str, Any], r: int, ckpt: str) -> str:
    """How the card's figures were measured, and the msta-eval command that reproduces them."""
    c = prog["rounds"][str(r)].get("eval_config")
    if not c:
        return ""
    masks = ", ".join(f"{float(m):.0%}" for m in prog["rounds"][str(r)].get("eval", {}))
    return (f"Evaluation (test masks {masks}): msta-eval's trials, {c['trials']} episodes of "
            f"{c['episode_length_s']:g} s over {', '.join(c['terrains'])} at levels "
            f"{', '.join(map(str, c['levels']))}, seed {c['seed']}; returns normalized by the "
            "teacher's on the same trials, 95 % intervals in the `_ci95_` metrics. "
            f"`msta-eval --policies teacher,{ckpt} --scenarios token_removal --suite "
            f"{c['suite']} --trials {c['trials']} --terrains {','.join(c['terrains'])} --levels "
            f"{','.join(map(str, c['levels']))} --episode_length_s {c['episode_length_s']:g} --seed "
            f"{c['seed']}` reports the same figures.")


def push_round(cfg: Any, prog: dict[str, Any], r: int) -> dict[str, str]:
    """Push ``output_dir/round_<r>`` (msta-correct) with tag ``stage2-r<r>``.

    Args:
        cfg: the ``CorrectConfig``.
        prog: progress.json content (``dataset_source``, the round's train/eval records).
        r: the round.
    """
    ckpt = Path(cfg.output_dir) / f"round_{r}"
    src = prog.get("dataset_source") or dataset_source(cfg.dataset, Path(prog["dataset"]))
    metrics, table = round_eval(prog, r)
    notes = (f"Stage 2: online correction round {r}, retrained on the dataset plus the "
             f"student episodes of rounds 1-{r} labelled by the teacher "
             f"({prog['rounds'][str(r)].get('episodes_after')} episodes); started from "
             f"`{portable(cfg.policy.path)}`. {eval_note(prog, r, f'{cfg.push_to}@stage2-r{r}')}")
    card = _card(src, draccus.encode(cfg), 2, r, metrics, table, notes)
    return push_checkpoint(ckpt, cfg.push_to, f"stage2-r{r}", card, cfg.push_private,
                           "the round is finished; rerun with --resume=true to push it")

"""What a model card shows from ``msta-hub push --eval_json FILE``.

FILE is one of:

- msta-eval's ``metrics.json`` (``"msta_eval_version": 2``): the card shows the headline
  figures of one evaluated student, the same three msta-correct's round table and stage-2
  cards show (:data:`HEADLINE_FIGURES`): linear-velocity tracking and total reward
  normalized by the teacher's on the same trials, and survival, each with its 95 % interval
  and trial count, one table row per scenario and condition (terrain average). The test
  masks of ``token_removal`` (else the first condition run) also become flat metrics
  ``<figure>@mask<m>`` (``_ci95_low`` / ``_ci95_high`` bounds, ``eval_trials``) as on a
  stage-2 card, which ``msta-hub versions`` lists. The student is the one whose checkpoint
  revision (``msta.data.revision`` over the directory's files, as msta-eval records it)
  is the pushed directory's, the only student in the file, or ``--eval_policy``.
- ``{metric: number}``: flat metrics.
- ``{row: {column: number}}``: an evaluation table.

Anything else is a :class:`EvalJsonError` naming the file and what is wrong with it: a
card never silently loses the figures it was given.
"""

from __future__ import annotations

import json
import math
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from msta.data import hub_markdown as md
from msta.data.revision import checkpoint_revision

#: metrics.json formats this module reads (msta-eval's ``msta_eval_version``).
READABLE_VERSIONS = (2,)
#: The headline figures of an msta-eval run record, as msta-correct's round table, the
#: stage-2 model card and eval cards show them: (name, figure, metric); the returns
#: normalized by the teacher's on the same trials, survival raw. Defined here (msta_data
#: may not import eval); ``msta.eval.metrics`` uses this one.
HEADLINE_FIGURES: tuple[tuple[str, str, str], ...] = (
    ("lin_tracking_vs_teacher", "normalized", "lin_tracking"), ("survival", "raw", "survival"),
    ("total_vs_teacher", "normalized", "total"))
#: The scenario whose conditions become flat metrics (Table I's test masks).
HEADLINE_SCENARIO = "token_removal"


#: The largest file ``--eval_json`` / ``--config_json`` read (msta-eval's metrics.json of a
#: whole study is well under 1 MiB).
MAX_INPUT_BYTES = 16 << 20


class CardInputError(ValueError):
    """A file given for a card (``--eval_json``, ``--config_json``) that msta cannot use
    (the message names it and says why)."""


class EvalJsonError(CardInputError):
    """An ``--eval_json`` file msta cannot put on a card (the message says why)."""


def read_json_input(path: str | Path, option: str, max_bytes: int = MAX_INPUT_BYTES) -> Any:
    """The JSON value of ``path``, a regular file of at most ``max_bytes``.

    A FIFO, a device (``/dev/zero``), a socket or a directory is refused before anything is
    read (opening does not wait for a FIFO's writer), and so is a larger file.

    Args:
        path: the file.
        option: how the message names it (``--eval_json``).
        max_bytes: the size limit.

    Raises:
        CardInputError: one line naming the file and what is wrong with it.
    """
    path = Path(path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError as e:
        raise CardInputError(f"{option} {path}: cannot read it ({e.strerror})") from None
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):
        os.close(fd)
        raise CardInputError(f"{option} {path}: not a regular file (a device, FIFO, socket "
                             "or directory); refused, nothing was read")
    with os.fdopen(fd, "rb") as f:
        raw = f.read(max_bytes + 1) if st.st_size <= max_bytes else b""
    if st.st_size > max_bytes or len(raw) > max_bytes:
        raise CardInputError(f"{option} {path}: larger than {max_bytes:,} bytes; refused")
    try:
        return json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as e:
        first = str(e).splitlines()[0] if str(e) else ""
        raise CardInputError(f"{option} {path}: cannot read it as JSON ({type(e).__name__}: "
                             f"{first[:200]})") from None


@dataclass
class EvalFigures:
    """What goes on the card.

    Args:
        metrics: flat figures ``{name: value}`` (None: none).
        table: ``{row: {column: value}}`` (None: none).
        note: how the figures were measured (the card's Evaluation section).
        evaluation: the run's provenance for the card's front matter (``msta.evaluation``).
        warnings: things the user should hear (printed by msta-hub, not on the card).
    """

    metrics: dict[str, float] | None = None
    table: dict[str, dict[str, float]] | None = None
    note: str = ""
    evaluation: dict[str, Any] | None = None
    warnings: list[str] = field(default_factory=list)


def _number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def read_eval_json(path: str | Path, checkpoint: str | Path | None = None, policy: str = "",
                   ref: str = "") -> EvalFigures:
    """The card figures of ``path`` (module docstring).

    Args:
        path: the JSON file.
        checkpoint: the directory being pushed (picks the student of an msta-eval file).
        policy: the student's name in an msta-eval file (``--eval_policy``).
        ref: how the card names the pushed checkpoint (``user/name@tag``), for the
            msta-eval command that reproduces the figures.
    Raises:
        EvalJsonError: the file is not one of the three forms, or names no usable student.
    """
    path = Path(path)
    try:
        data = read_json_input(path, "--eval_json")
    except CardInputError as e:
        raise EvalJsonError(str(e)) from None
    if isinstance(data, dict) and "msta_eval_version" in data:
        try:
            return msta_eval_figures(data, path, checkpoint, policy, ref)
        except (KeyError, TypeError, AttributeError, IndexError, ValueError, OverflowError) as e:
            if isinstance(e, EvalJsonError):
                raise
            raise EvalJsonError(f"--eval_json {path}: not a well-formed msta-eval metrics.json "
                                f"({type(e).__name__}: {str(e)[:200]})") from None
    if policy:
        raise EvalJsonError(f"--eval_policy {policy!r}: {path} is not msta-eval's metrics.json")
    return _plain_figures(data, path)


def _plain_figures(data: Any, path: Path) -> EvalFigures:
    """``{metric: number}`` or ``{row: {column: number}}``."""
    what = ("expected msta-eval's metrics.json, {metric: number} or {row: {column: number}}")
    if not isinstance(data, dict) or not data:
        raise EvalJsonError(f"--eval_json {path}: {what}; it holds "
                            f"{'an empty object' if data == {} else type(data).__name__}")
    if all(isinstance(v, dict) for v in data.values()):
        for row, cols in data.items():
            bad = [c for c, v in cols.items() if not _number(v)]
            if bad or not cols:
                raise EvalJsonError(f"--eval_json {path}: row {row!r} "
                                    + (f"column {bad[0]!r} is not a finite number ({what})"
                                       if bad else "is empty"))
        return EvalFigures(table=data)
    bad = [k for k, v in data.items() if not _number(v)]
    if bad:
        raise EvalJsonError(f"--eval_json {path}: {bad[0]!r} is not a finite number ({what})")
    return EvalFigures(metrics=data)


def _pick_policy(data: dict, path: Path, checkpoint: str | Path | None, policy: str
                 ) -> tuple[dict, list[str]]:
    """The ``policies`` entry whose figures go on the card, and warnings."""
    entries = data["policies"]
    names = [p["name"] for p in entries]
    if policy:
        chosen = [p for p in entries if p["name"] == policy]
        if not chosen:
            raise EvalJsonError(f"--eval_policy {policy!r} is not in {path} (policies: "
                                f"{', '.join(names)})")
        return chosen[0], []
    students = [p for p in entries if p.get("kind") == "student"]
    if not students:
        raise EvalJsonError(f"--eval_json {path}: no student was evaluated (policies: "
                            f"{', '.join(names)})")
    if checkpoint is not None and Path(checkpoint).is_dir():
        rev = checkpoint_revision(checkpoint)
        same = [p for p in students if p.get("revision") == rev]
        if same:
            return same[0], []
        if len(students) == 1:
            return students[0], [
                f"{path} evaluated {students[0]['name']} (revision {students[0].get('revision')}"
                f"), whose files differ from {checkpoint} (revision {rev}); its figures go on "
                "the card"]
    if len(students) == 1:
        return students[0], []
    which = f"none has the files of {checkpoint}" if checkpoint is not None else "which one?"
    raise EvalJsonError(f"--eval_json {path} evaluated {len(students)} students and {which}: "
                        f"pass --eval_policy=NAME (one of "
                        f"{', '.join(p['name'] for p in students)})")


def _row(run: dict) -> dict[str, float]:
    """The headline figures of one run's terrain average, with bounds and trials."""
    row: dict[str, float] = {}
    for name, figure, key in HEADLINE_FIGURES:
        cell = run[figure]["per_terrain"]["average"]
        if _number(cell.get(key)):
            row[name] = cell[key]
            ci = (cell.get("ci") or {}).get(key)
            if ci and all(_number(b) for b in ci):
                row[f"{name}_ci95_low"], row[f"{name}_ci95_high"] = ci
    trials = run["normalized"]["per_terrain"]["average"]["trials"]
    if not _number(trials) or trials < 0:
        raise ValueError(f"run {run['policy']!r}: trials {trials!r} is not a count")
    row["trials"] = trials
    return row


def _suffix(run: dict) -> str:
    if run["scenario"] == HEADLINE_SCENARIO:
        return f"@mask{float(run['value']):g}"
    return f"@{run['scenario']}={run['value']}"


def _flat(run: dict, row: dict[str, float]) -> dict[str, float]:
    """``row`` as flat metrics named for the run's condition (``lin_tracking_vs_teacher@mask0``,
    ``..._ci95_low@mask0``), as a stage-2 card names them."""
    return {f"{k}{_suffix(run)}": v for k, v in row.items() if k != "trials"}


def msta_eval_figures(data: dict, path: Path, checkpoint: str | Path | None = None,
                      policy: str = "", ref: str = "") -> EvalFigures:
    """The card figures of msta-eval's metrics.json content ``data`` (module docstring)."""
    version = data.get("msta_eval_version")
    if version not in READABLE_VERSIONS:
        raise EvalJsonError(f"--eval_json {path}: written by msta-eval format {version!r}; this "
                            f"msta reads format {', '.join(map(str, READABLE_VERSIONS))} (run "
                            "msta-eval again)")
    missing = [k for k in ("config", "policies", "runs", "reference") if k not in data]
    if missing:
        raise EvalJsonError(f"--eval_json {path}: not a complete msta-eval metrics.json (no "
                            f"{missing[0]!r})")
    entry, warnings = _pick_policy(data, path, checkpoint, policy)
    runs = [r for r in data["runs"] if r["policy"] == entry["name"]]
    ok = [r for r in runs if r.get("status") == "ok"]
    if not ok:
        why = f"every run n/a: {runs[0].get('reason')}" if runs else "no run of it"
        raise EvalJsonError(f"--eval_json {path}: no figures for {entry['name']} ({why})")
    table = {f"{r['scenario']} {r['condition']}": _row(r) for r in ok}
    head = [r for r in ok if r["scenario"] == HEADLINE_SCENARIO] or ok[:1]
    metrics: dict[str, float] = {}
    for r in head:
        metrics.update(_flat(r, table[f"{r['scenario']} {r['condition']}"]))
    metrics["eval_trials"] = table[f"{head[0]['scenario']} {head[0]['condition']}"]["trials"]
    cfg = data["config"]
    evaluation = {"format": version, "policy": entry["name"], "revision": entry.get("revision"),
                  **{k: cfg[k] for k in ("suite", "scenarios", "trials", "terrains", "levels",
                                         "episode_length_s", "seed") if k in cfg},
                  "teacher": {"type": (cfg.get("teacher") or {}).get("type"),
                              "revision": data["reference"].get("revision")}}
    return EvalFigures(metrics, table, _note(data, entry, runs, ref), evaluation, warnings)


def reproduce_command(cfg: dict[str, Any], ref: str) -> str:
    """The msta-eval command that runs the trials of a metrics.json ``config`` again on
    ``ref`` (figures equal on the same device type); each value one shell word."""
    q = md.shell
    parts = [f"msta-eval --policies {q('teacher,' + (ref or '<checkpoint>'))}",
             f"--suite {q(cfg['suite'])}", f"--scenarios {q(','.join(cfg['scenarios']))}",
             f"--trials {q(cfg['trials'])}", f"--terrains {q(','.join(cfg['terrains']))}",
             f"--levels {q(','.join(map(str, cfg['levels'])))}",
             f"--episode_length_s {cfg['episode_length_s']:g}",
             f"--num_envs {q(cfg['num_envs'])}", f"--seed {q(cfg['seed'])}",
             f"--teacher.type={q(cfg['teacher']['type'])}"]
    parts += [f"--{k}=false" for k in ("noise", "randomization", "heading_commands")
              if cfg.get(k) is False]
    if cfg.get("num_threads", 1) != 1:
        parts.append(f"--num_threads {q(cfg['num_threads'])}")
    if cfg.get("faults"):
        parts.append(f"--faults {q(','.join(cfg['faults']))}")
    if cfg.get("device", "cpu") not in ("cpu", "auto"):
        parts.append(f"--device {q(cfg['device'])}")
    return " ".join(parts)


def _note(data: dict, entry: dict, runs: list[dict], ref: str) -> str:
    """How the card's figures were measured, what was not applicable, and the command."""
    cfg, per = data["config"], data["reference"].get("per_terrain", {})
    each = sorted({per[t]["trials"] for t in data.get("terrains", []) if t in per})
    each = [md.text(n) for n in each]
    spread = (f" ({each[0]} per terrain)" if len(each) == 1 else
              f" ({each[0]}-{each[-1]} per terrain)" if each else "")
    t, c = md.text, md.code
    text = (f"Figures from msta-eval's metrics.json (format {t(data['msta_eval_version'])}) for "
            f"{c(entry['name'])} (checkpoint revision {c(entry.get('revision'))}): "
            f"{t(cfg['trials'])} trials per row{spread}, one trial = one "
            f"{cfg['episode_length_s']:g} s episode, terrains {t(', '.join(cfg['terrains']))} at "
            f"levels {t(', '.join(map(str, cfg['levels'])))}, seed {t(cfg['seed'])}; reference "
            f"teacher {c(cfg['teacher']['type'])} (revision "
            f"{c(data['reference'].get('revision'))}). "
            "Tracking and total reward are per-step returns normalized by the teacher's on the "
            "same trials, survival the share of episodes without a fall; each figure is the "
            "terrain average with its 95 % interval (`± half-width`: Student t, or the delta "
            "method for ratios; `(low–high)`: Wilson).")
    na = [t(f"{r['scenario']} {r['condition']} ({r.get('reason', '')})") for r in runs
          if r.get("status") != "ok"]
    if na:
        text += " Not applicable: " + "; ".join(na) + "."
    return text + f"\n\n{c(reproduce_command(cfg, ref))} runs the same trials."

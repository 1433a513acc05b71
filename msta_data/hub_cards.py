"""Cards (README.md: YAML front matter plus Markdown): dataset cards, and what model cards
(:mod:`msta.data.hub_model_card`) share with them: :class:`CardInfo`, the figures' tables
and reading cards back.

A dataset card follows LeRobot's (``lerobot.datasets.utils.create_lerobot_dataset_card``:
``license``, ``tags`` starting with ``LeRobot``, ``task_categories: [robotics]``, the
``configs`` entry the hub's viewer reads) plus ``robot_type`` and ``fps``; its body has a
usage snippet, the provenance summary (episodes and frames by source, stage-2 round and
terrain type, counted from the episode table) and a table of every feature. The writer
rebuilds it after every commit (:func:`write_dataset_card`) and ``push_dataset`` before
every push, so its counts are those of ``meta/info.json``. A card holds no local path
(:func:`portable`), and names and values from users or files are inert text
(:mod:`msta.data.hub_markdown`).
"""

from __future__ import annotations

import json
import os
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from huggingface_hub import CardData, RepoCard

from msta.data import features as F
from msta.data import hub_markdown as md
from msta.data import layout as L
from msta.data import sensors as registry
from msta.data.figures import fmt_ci


@dataclass
class CardInfo:
    """What a model or dataset card records (all optional).

    Args:
        dataset_repo: hub id of the training dataset.
        dataset_revision: the dataset's commit sha or tag used for training.
        config: training or collection configuration (JSON-like).
        stage: training stage (1 = offline behaviour cloning, 2 = online correction).
        round: correction round within the stage.
        metrics: flat summary metrics {name: value}.
        eval_table: evaluation table {row: {column: value}}.
        title: heading of the card.
        notes: free text appended to the card's Training section.
        eval_note: how the figures were measured (the card's Evaluation section).
        evaluation: the evaluation's provenance (front matter ``msta.evaluation``).
        base_model: hub id of the checkpoint this one was trained from (front matter
            ``base_model``); default: what the checkpoint's run configuration names.

    ``notes`` and ``eval_note`` are Markdown written by msta (a value quoted in them goes
    through :mod:`msta.data.hub_markdown`); every other string is shown as inert text.

    A figure ``X`` with bounds ``X_ci95_low`` / ``X_ci95_high`` (a metric ``X@m`` with
    ``X_ci95_low@m``; a table column likewise) is shown as one cell, ``0.85 ±0.10`` or
    ``0.80 (0.49–0.94)``; the front matter keeps every number.
    """

    dataset_repo: str | None = None
    dataset_revision: str | None = None
    config: dict[str, Any] | None = None
    stage: int | str | None = None
    round: int | None = None
    metrics: dict[str, float] | None = None
    eval_table: dict[str, dict[str, float]] | None = None
    title: str | None = None
    notes: str = ""
    eval_note: str = ""
    evaluation: dict[str, Any] | None = None
    base_model: str | None = None

    def msta_metadata(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        if self.dataset_repo:
            out["dataset"] = {"repo": portable(self.dataset_repo), "revision": self.dataset_revision}
        for key in ("stage", "round", "metrics", "eval_table", "evaluation", "config"):
            value = getattr(self, key)
            if value is not None:
                out[key] = portable(value) if key == "config" else value
        return out


#: The license of msta's checkpoints and datasets (the project's, pyproject.toml).
LICENSE = "apache-2.0"
#: What each training stage is (a model card's "Training" section).
STAGES = {1: "offline behaviour cloning of the teacher's rollouts",
          2: "online correction: the student drives, the teacher labels, the dataset grows"}


def portable(obj: Any) -> Any:
    """``obj`` (a JSON-like config) as a public card may show it: no ``output_dir``, and an
    absolute local path becomes ``<local>/<its last part>``."""
    if isinstance(obj, dict):
        return {k: portable(v) for k, v in obj.items() if k != "output_dir"}
    if isinstance(obj, list):
        return [portable(v) for v in obj]
    if isinstance(obj, str) and (os.path.isabs(obj) or obj.startswith("~")):
        return f"<local>/{Path(obj).name}"
    return obj


class Shown(str):
    """A cell msta formatted from numbers (``0.93 ±0.03``): written as it is."""


def _cell(value: Any) -> str:
    """Counts as they are (46653, not 4.665e+04); other numbers to 4 significant digits;
    text as inert Markdown (:func:`msta.data.hub_markdown.text`)."""
    if isinstance(value, Shown):
        return str(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return md.text(value)
    return str(value) if isinstance(value, int) else f"{value:.4g}"


def _markdown_table(table: dict[str, dict[str, Any]], corner: str = "") -> str:
    columns = list(dict.fromkeys(c for row in table.values() for c in row))
    lines = [f"| {md.text(corner)} | " + " | ".join(map(md.text, columns)) + " |",
             "|---" * (len(columns) + 1) + "|"]
    for name, row in table.items():
        lines.append(f"| {md.text(name)} | " + " | ".join(_cell(row.get(c, "")) for c in columns)
                     + " |")
    return "\n".join(lines)


def front_matter(metadata: dict[str, Any]) -> str:
    return f"---\n{CardData(**metadata).to_yaml()}\n---\n\n"


# ----- figures ---------------------------------------------------------------------------
def bounds_key(key: str, end: str) -> str:
    """``X`` -> ``X_ci95_<end>``; ``X@m`` -> ``X_ci95_<end>@m``."""
    name, at, cond = key.partition("@")
    return f"{name}_ci95_{end}{at}{cond}"


def with_intervals(row: dict[str, Any]) -> dict[str, Any]:
    """``row`` with each figure's ``_ci95_low`` / ``_ci95_high`` bounds folded into its cell
    (:func:`msta.data.figures.fmt_ci`); figures without bounds as they are."""
    out: dict[str, Any] = {}
    for key, value in row.items():
        if "_ci95_low" in key or "_ci95_high" in key:
            continue
        low, high = row.get(bounds_key(key, "low")), row.get(bounds_key(key, "high"))
        if isinstance(value, (int, float)) and isinstance(low, (int, float)) \
                and isinstance(high, (int, float)):
            value = Shown(fmt_ci(value, (low, high)))
        out[key] = value
    return out


def evaluation_section(info: CardInfo) -> list[str]:
    out = []
    if info.metrics:
        shown = with_intervals(info.metrics)
        out += ["## Metrics", "", "| metric | value |", "|---|---|",
                *(f"| {md.text(k)} | {_cell(v)} |" for k, v in shown.items()), ""]
    if info.eval_table:
        trials = sorted({int(row["trials"]) for row in info.eval_table.values()
                         if isinstance(row.get("trials"), (int, float))})
        count = (f"{trials[0]} trials (episodes) per row" if len(trials) == 1 else
                 "trials per row in the `trials` column" if trials else "trial count not recorded")
        table = {row: with_intervals(cols) for row, cols in info.eval_table.items()}
        out += ["## Evaluation", "", f"{count}.", "", _markdown_table(table), ""]
    if info.eval_note:
        out += ([] if info.eval_table else ["## Evaluation", ""]) + [info.eval_note, ""]
    return out


# ----- dataset cards ---------------------------------------------------------------------
#: What the columns that are not registry sensors hold (a dataset card's features table).
COLUMN_DESCRIPTIONS = {
    "observation.state": "the student sensors concatenated",
    "observation.environment_state": "the velocity command (a copy of command.*)",
    "action": "the teacher's action label: joint offsets from the default pose",
    "executed_action": "the action applied (the student's in stage 2)",
    "next.reward": "total reward of the step",
    "next.lin_vel_tracking": "linear-velocity tracking reward of the step",
    "next.ang_vel_tracking": "yaw-rate tracking reward of the step",
    "next.done": "the episode ended after this step",
    "timestamp": "time since the episode start (s)",
    "frame_index": "step within the episode",
    "episode_index": "episode number",
    "index": "frame number in the dataset",
    "task_index": "row of meta/tasks.parquet (one task per terrain type)",
}
#: Channel names listed in full up to this many (then the first and last few).
MAX_LISTED_CHANNELS = 12
#: Provenance groups of a dataset card: summary key -> episode-table column.
PROVENANCE_GROUPS = {"by_source": "provenance/source", "by_round": "provenance/round",
                     "by_terrain": "provenance/terrain"}
#: Row order of each provenance group: sources as ``features.SOURCES``, rounds by number.
_ORDER = {
    "by_source": lambda v: (F.SOURCES.index(v) if v in F.SOURCES else len(F.SOURCES), v),
    "by_round": lambda v: (int(v) if v.isdigit() else -1, v),
    "by_terrain": lambda v: (0, v),
}


def _channels(names: list[str] | dict[str, Any] | None) -> str:
    if isinstance(names, dict):  # LeRobot's older {"motors": [...]} form
        names = [str(n) for v in names.values() for n in (v if isinstance(v, list) else [v])]
    if not names:
        return ""
    names = [str(n) for n in names]
    if len(names) <= MAX_LISTED_CHANNELS:
        return md.code(", ".join(names), in_table=True)
    return (f"{len(names)} channels "
            + md.code(f"{', '.join(names[:3])}, ..., {', '.join(names[-2:])}", in_table=True))


def features_table(features: dict[str, dict[str, Any]]) -> str:
    """Markdown table of every feature: name, dtype, shape, description and channel names."""
    sensor_of = F.sensor_column_to_name(features)
    lines = ["| feature | dtype | shape | description; channels |", "|---|---|---|---|"]
    for col, ft in features.items():
        desc = (registry.get(sensor_of[col]).description if col in sensor_of
                else COLUMN_DESCRIPTIONS.get(col, ""))
        text = "; ".join(p for p in (md.text(desc), _channels(ft.get("names"))) if p)
        shape = "(" + ", ".join(map(md.text, ft["shape"])) + ("," if len(ft["shape"]) == 1
                                                               else "") + ")"
        lines.append(f"| {md.code(col, in_table=True)} | {md.text(ft['dtype'])} | {shape} | "
                     f"{text} |")
    return "\n".join(lines)


def provenance_summary(root: str | Path, info: dict[str, Any]) -> dict[str, dict[str, dict]]:
    """Episodes and frames of the committed episodes by source, stage-2 round and terrain.

    Args:
        root: dataset root.
        info: its ``meta/info.json`` (``total_episodes`` bounds the rows counted).

    Returns:
        ``{"by_source" | "by_round" | "by_terrain": {value: {"episodes", "frames"}}}``;
        rounds as strings; ``unknown`` where the episode table has no provenance column.
    """
    table = F.read_episode_table(root, info)
    lengths = table.column("length").to_pylist()
    out: dict[str, dict[str, dict]] = {}
    for key, col in PROVENANCE_GROUPS.items():
        values = (table.column(col).to_pylist() if col in table.column_names
                  else ["unknown"] * len(lengths))
        episodes, frames = Counter(map(str, values)), Counter()
        for value, n in zip(values, lengths, strict=True):
            frames[str(value)] += n
        out[key] = {v: {"episodes": episodes[v], "frames": frames[v]}
                    for v in sorted(episodes, key=_ORDER[key])}
    return out



def _dataset_body(info: CardInfo, dataset_info: dict[str, Any] | None, repo_id: str,
                  provenance: dict[str, dict[str, dict]] | None) -> list[str]:
    repo = repo_id or "<user/name>"
    body = [f"# {md.text(info.title or f'MSTA dataset {repo_id}'.strip())}", "",
            "A quadruped-locomotion dataset recorded with msta in LeRobot's v3.0 format.", ""]
    if dataset_info:
        got = {k: md.text(dataset_info.get(k)) for k in (
            "robot_type", "fps", "total_episodes", "total_frames", "total_tasks")}
        body += [f"- **Robot**: {got['robot_type']}, {got['fps']} frames per second",
                 f"- **Episodes**: {got['total_episodes']}, **frames**: {got['total_frames']}, "
                 f"**tasks**: {got['total_tasks']}",
                 f"- **License**: `{LICENSE}` (Apache License 2.0)", ""]
    body += ["## Usage", "", "```python", "from lerobot.datasets.lerobot_dataset import LeRobotDataset",
             "", f"dataset = LeRobotDataset({md.python_str(repo)}, "
             f"revision={md.python_str(F.CODEBASE_VERSION)})", "```", "", "```bash",
             f"msta-train --dataset={md.shell(f'datasets/{repo}@{F.CODEBASE_VERSION}')}", "```",
             ""]
    if provenance:
        titles = {"by_source": "source", "by_round": "stage-2 round (0: teacher data)",
                  "by_terrain": "terrain"}
        body += ["## Provenance", "", "Counted from the `provenance/*` columns of the episode "
                 f"table (`{L.EPISODES_DIR}/`).", ""]
        for key, rows in provenance.items():
            body += [_markdown_table(rows, titles.get(key, key)), ""]
    if dataset_info and dataset_info.get("features"):
        body += ["## Features", "", features_table(dataset_info["features"]), "",
                 f"Everything else LeRobot records is in [{L.INFO_PATH}]({L.INFO_PATH}).", ""]
    return [*body, *evaluation_section(info), info.notes]


def dataset_card(info: CardInfo, dataset_info: dict[str, Any] | None = None, repo_id: str = "",
                 provenance: dict[str, dict[str, dict]] | None = None) -> str:
    """README.md text for a LeRobot dataset root.

    Args:
        info: what to record (config = the collection configuration).
        dataset_info: the dataset's meta/info.json (robot type, fps, sizes, features).
        repo_id: used in the default title and the usage snippet.
        provenance: :func:`provenance_summary` of the dataset.
    """
    meta: dict[str, Any] = {"license": LICENSE, "tags": ["LeRobot", "msta", "robotics", "quadruped"],
                            "task_categories": ["robotics"],
                            "configs": [{"config_name": "default", "data_files": L.DATA_FILES_GLOB}]}
    msta = info.msta_metadata()
    if dataset_info:
        meta.update({k: dataset_info[k] for k in ("robot_type", "fps") if k in dataset_info})
        msta["lerobot"] = {k: dataset_info[k] for k in (
            "codebase_version", "robot_type", "fps", "total_episodes", "total_frames",
            "total_tasks") if k in dataset_info}
    if provenance:
        msta["provenance"] = provenance
    meta["msta"] = msta
    body = _dataset_body(info, dataset_info, repo_id, provenance)
    return front_matter(meta) + "\n".join(body).rstrip() + "\n"


def root_dataset_card(root: str | Path, card: CardInfo | None = None, repo_id: str = ""
                      ) -> str | None:
    """The card of dataset ``root`` as its files are now, or None to keep its README.md.

    Args:
        root: dataset root (meta/info.json, the episode table).
        card: what to record; default: what msta's card already in ``root`` records. A
            README.md of the user's own (no ``msta`` block) is kept unless ``card`` is given.
        repo_id: title and usage snippet; default: ``meta/msta.json``'s ``repo_id``.
    """
    root = Path(root)
    existing = root / L.CARD_NAME
    if card is None and existing.is_file():
        meta = card_metadata(existing.read_text(encoding="utf-8"))
        if "msta" not in meta:
            return None
        card = card_info(meta)
    info = json.loads(L.info_path(root).read_text())
    if not repo_id and (root / L.MSTA_META_PATH).is_file():
        repo_id = str(json.loads((root / L.MSTA_META_PATH).read_text()).get("repo_id") or "")
    return dataset_card(card or CardInfo(), info, repo_id, provenance_summary(root, info))


def write_dataset_card(root: str | Path) -> bool:
    """Rebuild ``root/README.md`` from the dataset's files (the writer calls it after each
    commit); a README.md of the user's own is kept. Returns whether the card was written."""
    root = Path(root)
    text = root_dataset_card(root)
    if text is None:
        return False
    tmp = root / L.META_DIR / f"{L.CARD_NAME}.tmp"  # meta/*.tmp: a writer removes leftovers
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, root / L.CARD_NAME)
    return True


# ----- reading cards back ----------------------------------------------------------------
def card_metadata(text: str) -> dict[str, Any]:
    """The YAML front matter of a card as a dict ({} when there is none)."""
    return RepoCard(text, ignore_metadata_errors=True).data.to_dict()


def card_info(metadata: dict[str, Any]) -> CardInfo:
    """The :class:`CardInfo` an msta card's front matter records (its ``msta`` block), so
    the card can be rebuilt with new figures."""
    msta = metadata.get("msta") or {}
    dataset = msta.get("dataset") or {}
    return CardInfo(dataset_repo=dataset.get("repo"), dataset_revision=dataset.get("revision"),
                    config=msta.get("config"), stage=msta.get("stage"), round=msta.get("round"),
                    metrics=msta.get("metrics"), eval_table=msta.get("eval_table"),
                    evaluation=msta.get("evaluation"))


def card_metrics(metadata: dict[str, Any]) -> dict[str, float]:
    """Figures recorded in a card: ``msta.metrics``, ``msta.eval_table`` as ``row/column``,
    and a dataset card's ``episodes`` and ``frames`` (``msta.lerobot``)."""
    msta = metadata.get("msta") or {}
    out = {k: v for k, v in (msta.get("metrics") or {}).items() if isinstance(v, (int, float))}
    for row, cols in (msta.get("eval_table") or {}).items():
        for col, v in (cols or {}).items():
            if isinstance(v, (int, float)):
                out[f"{row}/{col}"] = v
    sizes = msta.get("lerobot") or {}
    for name, key in (("episodes", "total_episodes"), ("frames", "total_frames")):
        if isinstance(sizes.get(key), int):
            out[name] = sizes[key]
    return out

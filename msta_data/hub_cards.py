"""Model and dataset cards (README.md: YAML front matter plus markdown) and their metrics."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from huggingface_hub import CardData, RepoCard

from msta_data import layout as L


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
        notes: free text appended to the card.
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

    def msta_metadata(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        if self.dataset_repo:
            out["dataset"] = {"repo": self.dataset_repo, "revision": self.dataset_revision}
        for key in ("stage", "round", "metrics", "eval_table", "config"):
            value = getattr(self, key)
            if value is not None:
                out[key] = value
        return out


def _markdown_table(table: dict[str, dict[str, float]]) -> str:
    columns = list(dict.fromkeys(c for row in table.values() for c in row))
    lines = ["| | " + " | ".join(columns) + " |", "|---" * (len(columns) + 1) + "|"]
    for name, row in table.items():
        cells = [f"{row[c]:.4g}" if isinstance(row.get(c), (int, float)) else str(row.get(c, "")) for c in columns]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _render_card(metadata: dict[str, Any], title: str, info: CardInfo, extra: str = "") -> str:
    body = [f"# {title}", ""]
    if info.dataset_repo:
        rev = f" @ `{info.dataset_revision}`" if info.dataset_revision else ""
        body += [f"Trained on dataset `{info.dataset_repo}`{rev}.", ""]
    if info.stage is not None:
        body += [f"Stage {info.stage}" + (f", round {info.round}" if info.round is not None else "") + ".", ""]
    if info.metrics:
        body += ["## Metrics", "", _markdown_table({"value": info.metrics}), ""]
    if info.eval_table:
        body += ["## Evaluation", "", _markdown_table(info.eval_table), ""]
    body += [extra, info.notes]
    return f"---\n{CardData(**metadata).to_yaml()}\n---\n\n" + "\n".join(body).rstrip() + "\n"


#: The license of msta's checkpoints and datasets (the project's, pyproject.toml).
LICENSE = "apache-2.0"


def model_card(info: CardInfo, repo_id: str = "", revision: str | None = None) -> str:
    """README.md text (YAML front matter + markdown) for a checkpoint: what it was trained
    on, its figures, a usage snippet and the license; local paths are never written.

    Args:
        info: what to record.
        repo_id: used in the default title and the usage snippet.
        revision: the tag the checkpoint is pushed with (in the usage snippet).
    """
    meta: dict[str, Any] = {"library_name": "msta", "license": LICENSE,
                            "tags": ["msta", "robotics", "quadruped", "lerobot"]}
    if info.dataset_repo:
        meta["datasets"] = [info.dataset_repo]
    meta["msta"] = info.msta_metadata()
    ref = f"{repo_id}@{revision}" if repo_id and revision else repo_id or "<user/name@tag>"
    usage = "\n".join([
        "## Usage", "", "```python", "from policies.factory import load_policy", "",
        f'policy = load_policy("{ref}")  # or a local checkpoint directory',
        "actions = policy.act(batch)  # batch: sensor windows, see docs/msta_model.md", "```",
        "", "```bash", f"msta-eval --policies teacher,{ref} --suite quick", "```", ""])
    return _render_card(meta, info.title or f"MSTA checkpoint {repo_id}".strip(), info, usage)


def dataset_card(info: CardInfo, dataset_info: dict[str, Any] | None = None, repo_id: str = "") -> str:
    """README.md text for a LeRobot dataset root.

    Args:
        info: what to record (config = the collection configuration).
        dataset_info: the dataset's meta/info.json (robot type, fps, sizes, features).
        repo_id: used in the default title.
    """
    meta: dict[str, Any] = {"license": LICENSE, "tags": ["LeRobot", "msta", "robotics", "quadruped"],
                            "task_categories": ["robotics"],
                            "configs": [{"config_name": "default", "data_files": L.DATA_FILES_GLOB}]}
    msta = info.msta_metadata()
    if dataset_info:
        msta["lerobot"] = {k: dataset_info[k] for k in ("codebase_version", "robot_type", "fps",
                                                           "total_episodes", "total_frames") if k in dataset_info}
    meta["msta"] = msta
    extra = ""
    if dataset_info:
        extra = f"## {L.INFO_PATH}\n\n```json\n" + json.dumps(dataset_info, indent=2) + "\n```\n"
    return _render_card(meta, info.title or f"MSTA dataset {repo_id}".strip(), info, extra)


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
                    metrics=msta.get("metrics"), eval_table=msta.get("eval_table"))


def card_metrics(metadata: dict[str, Any]) -> dict[str, float]:
    """Metrics recorded in a card: ``msta.metrics`` plus ``msta.eval_table`` as ``row/column``."""
    msta = metadata.get("msta") or {}
    out = {k: v for k, v in (msta.get("metrics") or {}).items() if isinstance(v, (int, float))}
    for row, cols in (msta.get("eval_table") or {}).items():
        for col, v in (cols or {}).items():
            if isinstance(v, (int, float)):
                out[f"{row}/{col}"] = v
    return out

"""Tags, branches and commits of a hub repo, with the metrics each commit's card records."""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from huggingface_hub import HfApi

from msta.data import layout as L
from msta.data.hub_cards import card_metadata, card_metrics
from msta.data.hub_ids import hub_api, parse_hub_id


@dataclass
class Version:
    """One commit of a repo with the refs pointing at it and its card's metrics."""

    sha: str
    title: str
    date: str
    authors: list[str]
    tags: list[str] = field(default_factory=list)
    branches: list[str] = field(default_factory=list)
    metrics: dict[str, float] = field(default_factory=dict)
    card: dict[str, Any] = field(default_factory=dict)


@dataclass
class RepoVersions:
    """Tags, branches and commits (newest first) of a repo."""

    repo_id: str
    repo_type: str
    tags: dict[str, str]
    branches: dict[str, str]
    commits: list[Version]

    def to_dict(self) -> dict[str, Any]:
        return {"repo_id": self.repo_id, "repo_type": self.repo_type, "tags": self.tags,
                "branches": self.branches, "commits": [vars(c) for c in self.commits]}

    def to_text(self, width: int = 100, metric_lines: int = 3) -> str:
        """One line per commit (sha, date, title, refs), then its metrics on up to
        ``metric_lines`` indented lines; no line is longer than ``width`` characters (a long
        title is cut, refs that leave it no room go on their own lines; 95 % bounds
        (``*_ci95_*``) follow the other metrics, and those past ``metric_lines`` are counted:
        ``to_dict`` / ``msta-hub versions --json`` has them all)."""
        lines = [_fit(f"{self.repo_type} {self.repo_id}", width)]
        for c in self.commits:
            refs = ", ".join([f"branch {b}" for b in c.branches] + [f"tag {t}" for t in c.tags])
            head = f"{c.sha[:12]}  {c.date[:19]}  "
            tail = f"  [{refs}]" if refs else ""
            if len(head) + MIN_TITLE + len(tail) > width:  # many refs: lines of their own
                lines.append(_fit(head + c.title, width))
                names = refs.split(", ")
                names[0] = "[" + names[0]
                names[-1] += "]"
                lines += _packed(names, width, len(names), ", ", keep_end=False)
            else:
                lines.append(_fit(c.title, width - len(tail), head) + tail)
            figures = sorted(c.metrics.items(), key=lambda kv: "_ci95_" in kv[0])  # bounds last
            lines += _packed([f"{k}={v:.4g}" for k, v in figures], width, metric_lines)
        return "\n".join(lines)


#: Characters of a commit title kept on its line before the refs move to lines of their own.
MIN_TITLE = 20


def _fit(text: str, width: int, prefix: str = "") -> str:
    """``prefix + text``, the text's end cut with ``...`` to fit ``width`` characters."""
    room = width - len(prefix)
    return prefix + (text if len(text) <= room else text[: max(room - 3, 0)] + "...")


def _packed(items: list[str], width: int, max_lines: int, sep: str = " ",
            indent: str = "    ", keep_end: bool = True) -> list[str]:
    """``items`` packed into indented lines of at most ``width`` characters (an item too long
    for a line alone keeps its end, a metric's value: ``...e_name=0.5``, or with
    ``keep_end=False`` its start); past ``max_lines``, a count of the rest."""
    room = width - len(indent)
    items = [i if len(i) <= room else "..." + i[len(i) - room + 3:] if keep_end
             else _fit(i, room) for i in items]
    rows: list[list[str]] = []
    for item in items:
        if rows and len(sep.join([*rows[-1], item])) <= room:
            rows[-1].append(item)
        else:
            rows.append([item])
    if len(rows) <= max_lines:
        return [indent + sep.join(r) for r in rows]
    shown = rows[: max_lines - 1] if max_lines > 1 else []
    hidden = sum(map(len, rows)) - sum(map(len, shown))
    return ([indent + sep.join(r) for r in shown]
            + [f"{indent}... {hidden} more metrics (--json lists them all)"])


def _card_at(api: HfApi, repo_id: str, repo_type: str, sha: str, cache: dict[str, dict]) -> dict[str, Any]:
    info = api.get_paths_info(repo_id, [L.CARD_NAME], revision=sha, repo_type=repo_type)
    if not info:
        return {}
    blob = info[0].blob_id
    if blob not in cache:
        with tempfile.TemporaryDirectory() as tmp:
            path = api.hf_hub_download(repo_id, L.CARD_NAME, revision=sha, repo_type=repo_type, local_dir=tmp)
            cache[blob] = card_metadata(Path(path).read_text(encoding="utf-8"))
    return cache[blob]


def versions(repo_id: str, *, repo_type: str = "model", with_metrics: bool = True,
             endpoint: str | None = None, token: str | bool | None = None) -> RepoVersions:
    """Tags, branches and the commits of every branch, with metrics from each commit's card.

    Args:
        repo_id: ``user/name`` (a ``datasets/`` prefix selects the dataset repo).
        repo_type: "model" or "dataset".
        with_metrics: read each commit's README.md front matter (one request per commit).
        endpoint: hub URL (default HF_ENDPOINT).
        token: secret (default HF_TOKEN).
    """
    hub_id = parse_hub_id(repo_id, None if repo_id.startswith("datasets/") else repo_type)
    api = hub_api(endpoint, token)
    refs = api.list_repo_refs(hub_id.repo_id, repo_type=hub_id.repo_type)
    tags = {t.name: t.target_commit for t in refs.tags}
    branches = {b.name: b.target_commit for b in refs.branches}
    seen: dict[str, Version] = {}
    for branch in sorted(branches, key=lambda b: b != "main"):
        for c in api.list_repo_commits(hub_id.repo_id, repo_type=hub_id.repo_type, revision=branch):
            if c.commit_id not in seen:
                seen[c.commit_id] = Version(c.commit_id, c.title, c.created_at.isoformat(), list(c.authors))
    cards: dict[str, dict] = {}
    for v in seen.values():
        v.tags = sorted(t for t, sha in tags.items() if sha == v.sha)
        v.branches = sorted(b for b, sha in branches.items() if sha == v.sha)
        if with_metrics:
            v.card = _card_at(api, hub_id.repo_id, hub_id.repo_type, v.sha, cards)
            v.metrics = card_metrics(v.card)
    commits = sorted(seen.values(), key=lambda v: v.date, reverse=True)
    return RepoVersions(hub_id.repo_id, hub_id.repo_type, tags, branches, commits)

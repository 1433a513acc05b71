"""Versioned sharing of checkpoints and datasets through a Hugging Face–compatible hub.

Everything goes through the huggingface_hub client. The endpoint and token come from
``HF_ENDPOINT`` / ``HF_TOKEN`` (read when a function runs, so they may be set after import)
unless passed explicitly; nothing names a host. Hub ids look like ``user/name[@revision]``
(``datasets/user/name[@revision]`` for datasets); a revision is a branch, a tag or a commit sha.

Pulls resolve the revision to one commit, download into a temporary directory next to the
destination, check every file against the hub's hashes (sha256 for LFS files, the git blob
sha1 otherwise) and only then rename the directory into place. Nothing here unpickles.
"""

from __future__ import annotations

import json
import logging
import os
import re
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from huggingface_hub import CardData, CommitOperationAdd, CommitOperationDelete, HfApi, RepoCard
from huggingface_hub.errors import RepositoryNotFoundError, RevisionNotFoundError

logger = logging.getLogger(__name__)

PICKLE_SUFFIXES = (".pt", ".pth", ".pkl", ".pickle", ".bin", ".ckpt", ".joblib")
_SKIP_DIRS = (".git", ".cache/huggingface")
_HUB_ID_RE = re.compile(
    r"^(?:(?P<type>datasets|models)/)?(?P<repo>[A-Za-z0-9][\w.-]*/[A-Za-z0-9][\w.-]*)(?:@(?P<rev>[^\s@]+))?$"
)


class HubError(RuntimeError):
    """A hub operation failed; the message names the repo, revision and local path involved."""


class HubIntegrityError(HubError):
    """Downloaded files do not match the hashes the hub reports."""


# ------------------------------------------------------------------ hub ids
@dataclass(frozen=True)
class HubId:
    """A parsed ``[datasets/]user/name[@revision]``."""

    repo_id: str
    revision: str | None = None
    repo_type: str = "model"

    def __str__(self) -> str:
        prefix = "datasets/" if self.repo_type == "dataset" else ""
        return f"{prefix}{self.repo_id}" + (f"@{self.revision}" if self.revision else "")


def parse_hub_id(spec: str, repo_type: str | None = None) -> HubId:
    """Parse ``[datasets/]user/name[@revision]``.

    Args:
        spec: the hub id.
        repo_type: "model" or "dataset"; overrides the ``datasets/`` prefix when given.
    """
    m = _HUB_ID_RE.match(spec.strip())
    if m is None:
        raise ValueError(f"'{spec}' is not a hub id of the form user/name[@revision]")
    kind = repo_type or ("dataset" if m.group("type") == "datasets" else "model")
    if kind not in ("model", "dataset"):
        raise ValueError(f"repo_type must be 'model' or 'dataset', got '{kind}'")
    return HubId(m.group("repo"), m.group("rev"), kind)


def is_hub_id(value: str | os.PathLike) -> bool:
    """True when ``value`` is not an existing local path and parses as a hub id."""
    text = os.fspath(value)
    return not Path(text).exists() and _HUB_ID_RE.match(text.strip()) is not None


def hub_api(endpoint: str | None = None, token: str | bool | None = None) -> HfApi:
    """An HfApi on ``endpoint`` (default: HF_ENDPOINT, else huggingface_hub's default).

    Args:
        endpoint: hub URL; None reads HF_ENDPOINT now.
        token: secret; None lets huggingface_hub read HF_TOKEN or its stored login; False sends none.
    """
    return HfApi(endpoint=endpoint or os.environ.get("HF_ENDPOINT") or None, token=token)


# ------------------------------------------------------------------ cards
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


def model_card(info: CardInfo, repo_id: str = "") -> str:
    """README.md text (YAML front matter + markdown) for a checkpoint.

    Args:
        info: what to record.
        repo_id: used in the default title.
    """
    meta: dict[str, Any] = {"library_name": "msta", "tags": ["msta", "robotics", "quadruped", "lerobot"]}
    if info.dataset_repo:
        meta["datasets"] = [info.dataset_repo]
    meta["msta"] = info.msta_metadata()
    return _render_card(meta, info.title or f"MSTA checkpoint {repo_id}".strip(), info)


def dataset_card(info: CardInfo, dataset_info: dict[str, Any] | None = None, repo_id: str = "") -> str:
    """README.md text for a LeRobot dataset root.

    Args:
        info: what to record (config = the collection configuration).
        dataset_info: the dataset's meta/info.json (robot type, fps, sizes, features).
        repo_id: used in the default title.
    """
    meta: dict[str, Any] = {"tags": ["LeRobot", "msta", "robotics", "quadruped"],
                            "task_categories": ["robotics"],
                            "configs": [{"config_name": "default", "data_files": "data/*/*.parquet"}]}
    msta = info.msta_metadata()
    if dataset_info:
        msta["lerobot"] = {k: dataset_info[k] for k in ("codebase_version", "robot_type", "fps",
                                                           "total_episodes", "total_frames") if k in dataset_info}
    meta["msta"] = msta
    extra = ""
    if dataset_info:
        extra = "## meta/info.json\n\n```json\n" + json.dumps(dataset_info, indent=2) + "\n```\n"
    return _render_card(meta, info.title or f"MSTA dataset {repo_id}".strip(), info, extra)


def card_metadata(text: str) -> dict[str, Any]:
    """The YAML front matter of a card as a dict ({} when there is none)."""
    return RepoCard(text, ignore_metadata_errors=True).data.to_dict()


def card_metrics(metadata: dict[str, Any]) -> dict[str, float]:
    """Metrics recorded in a card: ``msta.metrics`` plus ``msta.eval_table`` as ``row/column``."""
    msta = metadata.get("msta") or {}
    out = {k: v for k, v in (msta.get("metrics") or {}).items() if isinstance(v, (int, float))}
    for row, cols in (msta.get("eval_table") or {}).items():
        for col, v in (cols or {}).items():
            if isinstance(v, (int, float)):
                out[f"{row}/{col}"] = v
    return out


# ------------------------------------------------------------------ push
#: machine-local files never uploaded: the dataset writer's lock, MuJoCo's warning log
_SKIP_FILES = {".msta.lock", "MUJOCO_LOG.TXT"}


def _local_files(root: Path) -> dict[str, Path]:
    out = {}
    for path in sorted(root.rglob("*")):
        rel = path.relative_to(root).as_posix()
        if path.name in _SKIP_FILES:
            continue
        if path.is_file() and not any(rel == d or rel.startswith(d + "/") for d in _SKIP_DIRS):
            out[rel] = path
    return out


def _set_tag(api: HfApi, repo_id: str, repo_type: str, tag: str, sha: str, move: bool) -> None:
    current = {t.name: t.target_commit for t in api.list_repo_refs(repo_id, repo_type=repo_type).tags}
    if current.get(tag) == sha:
        return
    if tag in current:
        if not move:
            raise HubError(f"tag '{tag}' of {repo_id} already points to {current[tag][:12]}; "
                           "pass move_tag=True (--move-tag) to move it")
        api.delete_tag(repo_id, tag=tag, repo_type=repo_type)
    api.create_tag(repo_id, tag=tag, revision=sha, repo_type=repo_type)


def _commit_dir(api: HfApi, root: Path, repo_id: str, repo_type: str, *, branch: str, private: bool,
                card_text: str | None, message: str, allow_pickle: bool) -> str:
    """Make ``branch`` hold exactly the files of ``root`` (+ README.md from ``card_text``)."""
    if not root.is_dir():
        raise FileNotFoundError(f"{root} is not a directory")
    files = _local_files(root)
    if card_text is not None:
        files.pop("README.md", None)
    pickles = [p for p in files if p.lower().endswith(PICKLE_SUFFIXES)]
    if pickles and not allow_pickle:
        raise HubError(f"{root} holds pickle-format files {pickles}; save safetensors/JSON or pass allow_pickle=True")
    if not files and card_text is None:
        raise HubError(f"{root} is empty: nothing to push")
    api.create_repo(repo_id, repo_type=repo_type, private=private, exist_ok=True)
    if branch != "main":
        api.create_branch(repo_id, branch=branch, repo_type=repo_type, exist_ok=True)
    ops: list = [CommitOperationAdd(path_in_repo=rel, path_or_fileobj=str(p)) for rel, p in files.items()]
    if card_text is not None:
        ops.append(CommitOperationAdd(path_in_repo="README.md", path_or_fileobj=card_text.encode()))
    keep = {op.path_in_repo for op in ops}
    remote = api.list_repo_files(repo_id, repo_type=repo_type, revision=branch)
    ops += [CommitOperationDelete(path_in_repo=p) for p in remote if p not in keep]
    return api.create_commit(repo_id, operations=ops, commit_message=message, revision=branch,
                             repo_type=repo_type).oid


def push(checkpoint_dir: str | os.PathLike, repo_id: str, tag: str | None = None, private: bool = False, *,
         card: CardInfo | None = None, branch: str = "main", message: str | None = None,
         move_tag: bool = False, allow_pickle: bool = False, endpoint: str | None = None,
         token: str | bool | None = None) -> str:
    """Commit a checkpoint directory as the new state of ``branch`` of a model repo.

    Files absent from the directory are deleted in the repo, so every commit is a complete
    checkpoint. Unchanged content is not uploaded again.

    Args:
        checkpoint_dir: directory to upload (e.g. config.json + model.safetensors).
        repo_id: ``user/name``; created when missing.
        tag: tag to put on the new commit (e.g. ``stage1-r0``).
        private: create the repo as private (only applies when it is created).
        card: write README.md from this (replaces a README.md in the directory).
        branch: branch to commit to; created from main when missing.
        message: commit message.
        move_tag: move ``tag`` when it already exists on another commit (else HubError).
        allow_pickle: permit pickle-format files (.pt, .bin, .pkl, ...); refused by default.
        endpoint: hub URL (default HF_ENDPOINT).
        token: secret (default HF_TOKEN).

    Returns:
        The commit sha now at the head of ``branch``.
    """
    root = Path(checkpoint_dir)
    api = hub_api(endpoint, token)
    text = model_card(card, repo_id) if card is not None else None
    sha = _commit_dir(api, root, repo_id, "model", branch=branch, private=private, card_text=text,
                      message=message or f"push {root.name}", allow_pickle=allow_pickle)
    if tag:
        _set_tag(api, repo_id, "model", tag, sha, move_tag)
    logger.info("pushed %s to %s@%s (commit %s)", root, repo_id, tag or branch, sha[:12])
    return sha


def push_dataset(root: str | os.PathLike, repo_id: str, private: bool = False, *, card: CardInfo | None = None,
                 tag: str | None = None, message: str | None = None, endpoint: str | None = None,
                 token: str | bool | None = None) -> str:
    """Push a LeRobot dataset root to a dataset repo and tag it with its codebase version.

    The dataset is locked (no writer may append meanwhile) and verified first
    (``msta_data.integrity.verify_for_publish``: every committed file against the size and
    sha256 recorded at commit, no leftover of an unfinished commit); a bad file is an error
    naming it and nothing is uploaded.

    The codebase-version tag (e.g. ``v3.0``) is moved to the new commit, as LeRobot's own push
    does, so ``LeRobotDataset(repo_id, revision="v3.0")`` loads the latest push; ``tag`` marks
    this particular version and is never moved.

    Args:
        root: dataset root holding meta/info.json.
        repo_id: ``user/name`` of the dataset repo.
        private: create the repo as private.
        card: dataset card content; default: a card built from meta/info.json when the root
            has no README.md.
        tag: extra tag for this version.
        message: commit message.
        endpoint: hub URL (default HF_ENDPOINT).
        token: secret (default HF_TOKEN).

    Returns:
        The commit sha.
    """
    root = Path(root)
    info_path = root / "meta" / "info.json"
    if not info_path.is_file():
        raise FileNotFoundError(f"{root} is not a LeRobot dataset root: {info_path} is missing")
    info = json.loads(info_path.read_text())
    version = info.get("codebase_version")
    if not isinstance(version, str) or not version:
        raise HubError(f"{info_path} has no 'codebase_version'")
    from msta_data.integrity import verify_for_publish
    from msta_data.locking import lock_directory
    from msta_data.writer import DatasetLockedError

    try:  # no writer may append meanwhile
        lock: int | None = lock_directory(root, "a dataset writer", DatasetLockedError)
    except PermissionError:  # a read-only copy: nobody appends to it through msta
        lock = None
    try:
        verify_for_publish(root)  # refuses, naming the file, before anything is uploaded
        api = hub_api(endpoint, token)
        text = None
        if card is not None or not (root / "README.md").exists():
            text = dataset_card(card or CardInfo(), info, repo_id)
        sha = _commit_dir(api, root, repo_id, "dataset", branch="main", private=private,
                          card_text=text, message=message or f"push dataset {root.name}",
                          allow_pickle=False)
    finally:
        if lock is not None:
            os.close(lock)
    _set_tag(api, repo_id, "dataset", version, sha, move=True)
    if tag:
        _set_tag(api, repo_id, "dataset", tag, sha, move=False)
    logger.info("pushed dataset %s to %s (commit %s, tag %s)", root, repo_id, sha[:12], version)
    return sha


# ------------------------------------------------------------------ pull
def resolve(spec: str | HubId, repo_type: str | None = None, *, endpoint: str | None = None,
            token: str | bool | None = None) -> HubId:
    """The hub id with its revision resolved to a full commit sha.

    Args:
        spec: ``[datasets/]user/name[@revision]`` (no revision = main).
        repo_type: "model" or "dataset" (overrides the prefix).
        endpoint: hub URL (default HF_ENDPOINT).
        token: secret (default HF_TOKEN).
    """
    hub_id = spec if isinstance(spec, HubId) else parse_hub_id(spec, repo_type)
    info = hub_api(endpoint, token).repo_info(hub_id.repo_id, repo_type=hub_id.repo_type,
                                              revision=hub_id.revision or "main")
    if not info.sha:
        raise HubError(f"the hub returned no commit sha for {hub_id}")
    return HubId(hub_id.repo_id, info.sha, hub_id.repo_type)


def _verify(api: HfApi, hub_id: HubId, local: Path) -> None:
    check = api.verify_repo_checksums(hub_id.repo_id, repo_type=hub_id.repo_type, revision=hub_id.revision,
                                      local_dir=local)
    problems = [f"{m['path']} ({m['algorithm']} expected {m['expected'][:12]}, got {m['actual'][:12]})"
                for m in check.mismatches]
    problems += [f"{p} (missing)" for p in check.missing_paths]
    problems += [f"{p} (not in the repo)" for p in check.extra_paths]
    if problems:
        raise HubIntegrityError(f"{len(problems)} file(s) of {hub_id} do not match the hub's hashes: "
                                + "; ".join(problems))


def pull(spec: str, dest_dir: str | os.PathLike, *, repo_type: str | None = None, overwrite: bool = False,
         endpoint: str | None = None, token: str | bool | None = None) -> Path:
    """Download ``[datasets/]user/name[@revision]`` into ``dest_dir``, verified, all or nothing.

    Args:
        spec: hub id; the revision (branch, tag, sha, short sha) defaults to main.
        dest_dir: directory to create; must not exist or be empty unless ``overwrite``.
        repo_type: "model" or "dataset" (overrides a ``datasets/`` prefix).
        overwrite: replace an existing non-empty ``dest_dir`` (only after a verified download).
        endpoint: hub URL (default HF_ENDPOINT).
        token: secret (default HF_TOKEN).

    Returns:
        ``dest_dir`` as a Path.

    Raises:
        HubIntegrityError: a downloaded file does not match the hub's hash (nothing is written).
        HubError: the download failed (nothing is written).
    """
    dest = Path(dest_dir)
    if dest.exists() and (not dest.is_dir() or any(dest.iterdir())) and not overwrite:
        raise FileExistsError(f"{dest} exists and is not empty (pass overwrite=True to replace it)")
    api = hub_api(endpoint, token)
    hub_id = resolve(spec, repo_type, endpoint=api.endpoint, token=token)
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}.partial-", dir=dest.parent))
    try:
        api.snapshot_download(hub_id.repo_id, repo_type=hub_id.repo_type, revision=hub_id.revision,
                              local_dir=tmp)
        shutil.rmtree(tmp / ".cache" / "huggingface", ignore_errors=True)
        if (tmp / ".cache").is_dir() and not any((tmp / ".cache").iterdir()):
            (tmp / ".cache").rmdir()
        _verify(api, hub_id, tmp)
        if dest.exists():
            old = dest.with_name(f".{dest.name}.old-{os.getpid()}")
            os.rename(dest, old)
            os.rename(tmp, dest)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.rename(tmp, dest)
    except HubError as err:
        shutil.rmtree(tmp, ignore_errors=True)
        raise type(err)(f"pull of {spec} (commit {hub_id.revision}) failed: {err}; {dest} was not written") from None
    except (RepositoryNotFoundError, RevisionNotFoundError):
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    except Exception as err:
        shutil.rmtree(tmp, ignore_errors=True)
        raise HubError(f"pull of {spec} (commit {hub_id.revision}) into {dest} failed "
                       f"({type(err).__name__}: {err}); {dest} was not written") from err
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    logger.info("pulled %s (commit %s) into %s", spec, hub_id.revision, dest)
    return dest


def default_cache_dir() -> Path:
    """Where ``materialize`` keeps pulled revisions: MSTA_HUB_CACHE or ~/.cache/msta/hub."""
    return Path(os.environ.get("MSTA_HUB_CACHE") or Path.home() / ".cache" / "msta" / "hub")


def materialize(path_or_spec: str | os.PathLike, *, repo_type: str | None = None,
                cache_dir: str | os.PathLike | None = None, endpoint: str | None = None,
                token: str | bool | None = None) -> Path:
    """A local directory for a checkpoint/dataset path or hub id (pulled once per commit).

    Args:
        path_or_spec: an existing local directory, or ``[datasets/]user/name[@revision]``.
        repo_type: "model" or "dataset" for hub ids.
        cache_dir: where pulled commits live (default: ``default_cache_dir()``).
        endpoint: hub URL (default HF_ENDPOINT).
        token: secret (default HF_TOKEN).
    """
    if Path(path_or_spec).exists():
        return Path(path_or_spec)
    hub_id = resolve(os.fspath(path_or_spec), repo_type, endpoint=endpoint, token=token)
    target = Path(cache_dir or default_cache_dir()) / f"{hub_id.repo_type}s" / hub_id.repo_id / str(hub_id.revision)
    if target.is_dir() and any(target.iterdir()):
        return target
    return pull(str(hub_id), target, repo_type=hub_id.repo_type, overwrite=True, endpoint=endpoint, token=token)


# ------------------------------------------------------------------ versions
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

    def to_text(self) -> str:
        lines = [f"{self.repo_type} {self.repo_id}"]
        for c in self.commits:
            refs = ", ".join([f"branch {b}" for b in c.branches] + [f"tag {t}" for t in c.tags])
            metrics = " ".join(f"{k}={v:.4g}" for k, v in c.metrics.items())
            lines.append(f"{c.sha[:12]}  {c.date[:19]}  {c.title}" + (f"  [{refs}]" if refs else "")
                         + (f"  {metrics}" if metrics else ""))
        return "\n".join(lines)


def _card_at(api: HfApi, repo_id: str, repo_type: str, sha: str, cache: dict[str, dict]) -> dict[str, Any]:
    info = api.get_paths_info(repo_id, ["README.md"], revision=sha, repo_type=repo_type)
    if not info:
        return {}
    blob = info[0].blob_id
    if blob not in cache:
        with tempfile.TemporaryDirectory() as tmp:
            path = api.hf_hub_download(repo_id, "README.md", revision=sha, repo_type=repo_type, local_dir=tmp)
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

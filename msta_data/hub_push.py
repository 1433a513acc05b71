"""Push a checkpoint directory or a dataset root as one commit of a hub repo.

Every commit is the complete directory: files absent locally are deleted in the repo.
Pickle-format files are refused unless allowed; a dataset is locked and verified against
its checksum manifest before anything is uploaded. What belongs to this machine only (the
``.msta.lock`` of a directory a process holds, MuJoCo's log, quarantined files, caches) is
never pushed: :data:`PUSH_IGNORE_PATTERNS`, which also keeps them out of a plain
``HfApi().upload_folder(..., ignore_patterns=PUSH_IGNORE_PATTERNS)``.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from huggingface_hub import CommitOperationAdd, CommitOperationDelete, HfApi
from huggingface_hub.utils import DEFAULT_IGNORE_PATTERNS, filter_repo_objects

from msta.data import layout as L
from msta.data.errors import DatasetLockedError
from msta.data.hub_cards import CardInfo, root_dataset_card
from msta.data.hub_ids import HubError, hub_api
from msta.data.hub_model_card import checkpoint_facts, model_card
from msta.data.inside import files_under
from msta.data.integrity import verify_for_publish
from msta.data.locking import lock_directory

logger = logging.getLogger(__name__)

PICKLE_SUFFIXES = (".pt", ".pth", ".pkl", ".pickle", ".bin", ".ckpt", ".joblib")
#: Files that never leave the machine, as huggingface_hub ``ignore_patterns`` (fnmatch on the
#: path in the repo; ``*`` spans folders): the lock and MuJoCo's log in any folder, the
#: quarantine, and any ``.cache/`` folder (huggingface_hub's download metadata among them;
#: ``.git`` is in huggingface_hub's own defaults). msta's push filters with them, and
#: ``HfApi().upload_folder(folder_path=..., repo_id=..., ignore_patterns=PUSH_IGNORE_PATTERNS)``
#: filters the same files.
PUSH_IGNORE_PATTERNS: list[str] = [
    *(p for name in sorted(L.LOCAL_ONLY_FILES) for p in (name, f"*/{name}")),
    f"{L.QUARANTINE_DIR}/", ".cache/", "*/.cache/*"]


@dataclass(frozen=True)
class Pushed:
    """What a push made (given to ``push``'s and ``push_dataset``'s ``report``).

    Args:
        sha: the commit.
        url: the commit's page on the hub.
        ref: ``repo_id@tag`` (or ``@branch``) the push is reachable as.
        files: files the commit holds (README.md included).
        size: their bytes.
        deleted: files of the branch's previous commit that this one deletes.
    """

    sha: str
    url: str
    ref: str
    files: int
    size: int
    deleted: int

    def summary(self) -> str:
        """One line: what was committed, where, and the commit's URL."""
        gone = f", {self.deleted} deleted" if self.deleted else ""
        return (f"pushed {self.files} files ({self.size:,} bytes{gone}) to {self.ref}: "
                f"{self.url}")


def _local_files(root: Path, what: str = "folder to push") -> dict[str, Path]:
    """The regular files to push; a symbolic link anywhere under ``root`` is refused
    (following it would publish its target: :func:`msta.data.inside.files_under`)."""
    if not root.is_dir():
        raise FileNotFoundError(f"{root} is not a directory")
    files = files_under(root, what=what, links="refuse")
    keep = filter_repo_objects(files, ignore_patterns=DEFAULT_IGNORE_PATTERNS
                               + PUSH_IGNORE_PATTERNS)
    return {rel: files[rel] for rel in keep}


def _set_tag(api: HfApi, repo_id: str, repo_type: str, tag: str, sha: str, move: bool) -> None:
    current = {t.name: t.target_commit for t in api.list_repo_refs(repo_id, repo_type=repo_type).tags}
    if current.get(tag) == sha:
        return
    if tag in current:
        if not move:
            raise HubError(f"tag '{tag}' of {repo_id} already points to {current[tag][:12]}; "
                           "pass move_tag=True (--move_tag) to move it")
        api.delete_tag(repo_id, tag=tag, repo_type=repo_type)
    api.create_tag(repo_id, tag=tag, revision=sha, repo_type=repo_type)


def _count(files: dict[str, Path], card_text: str | None) -> int:
    """Files a commit of ``files`` (and a card) holds."""
    return len(set(files) | ({L.CARD_NAME} if card_text is not None else set()))


def _commit_dir(api: HfApi, root: Path, files: dict[str, Path], repo_id: str, repo_type: str, *,
                branch: str, private: bool, card_text: str | None, message: str,
                allow_pickle: bool) -> Pushed:
    """Make ``branch`` hold exactly ``files`` of ``root`` (+ README.md from ``card_text``)."""
    files = dict(files)
    if card_text is not None:
        files.pop(L.CARD_NAME, None)
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
        ops.append(CommitOperationAdd(path_in_repo=L.CARD_NAME, path_or_fileobj=card_text.encode()))
    keep = {op.path_in_repo for op in ops}
    remote = api.list_repo_files(repo_id, repo_type=repo_type, revision=branch)
    deletes = [CommitOperationDelete(path_in_repo=p) for p in remote if p not in keep]
    size = sum(p.stat().st_size for p in files.values()) + len((card_text or "").encode())
    info = api.create_commit(repo_id, operations=ops + deletes, revision=branch,
                             commit_message=message,
                             repo_type=repo_type)
    return Pushed(info.oid, info.commit_url, f"{repo_id}@{branch}", len(keep), size,
                  len(deletes))


def push(checkpoint_dir: str | os.PathLike, repo_id: str, tag: str | None = None, private: bool = False, *,
         card: CardInfo | None = None, branch: str = "main", message: str | None = None,
         move_tag: bool = False, allow_pickle: bool = False, endpoint: str | None = None,
         token: str | bool | None = None, report: Callable[[Pushed], None] | None = None
         ) -> str:
    """Commit a checkpoint directory as the new state of ``branch`` of a model repo.

    Files absent from the directory are deleted in the repo, so every commit is a complete
    checkpoint. Unchanged content is not uploaded again.

    Args:
        checkpoint_dir: directory to upload (e.g. config.json + model.safetensors).
        repo_id: ``user/name``; created when missing.
        tag: tag to put on the new commit (e.g. ``stage1-r0``).
        private: create the repo as private (only applies when it is created).
        card: write README.md from this (replaces a README.md in the directory;
            :func:`msta.data.hub_model_card.model_card`, for the checkpoint's layout).
        branch: branch to commit to; created from main when missing.
        message: commit message; default ``Upload <type> checkpoint <name> (<n> files)``.
        move_tag: move ``tag`` when it already exists on another commit (else HubError).
        allow_pickle: permit pickle-format files (.pt, .bin, .pkl, ...); refused by default.
        endpoint: hub URL (default HF_ENDPOINT).
        token: secret (default HF_TOKEN).
        report: called with the :class:`Pushed` (the commit's URL, what it holds).

    Returns:
        The commit sha now at the head of ``branch``.

    Raises:
        PathOutsideRootError: a symbolic link is under ``checkpoint_dir`` (named).
    """
    root = Path(checkpoint_dir)
    files = _local_files(root, "checkpoint")
    facts = checkpoint_facts(root)
    api = hub_api(endpoint, token)
    text = model_card(card, repo_id, tag, facts) if card is not None else None
    what = ("LeRobot " if facts.layout == "lerobot" else "") + (facts.policy_type or "msta")
    pushed = _commit_dir(api, root, files, repo_id, "model", branch=branch, private=private,
                         card_text=text, allow_pickle=allow_pickle, message=message or
                         f"Upload {what} checkpoint {facts.name} ({_count(files, text)} files)")
    if tag:
        _set_tag(api, repo_id, "model", tag, pushed.sha, move_tag)
        pushed = replace(pushed, ref=f"{repo_id}@{tag}")
    logger.info("pushed %s to %s (commit %s)", root, pushed.ref, pushed.sha[:12])
    if report is not None:
        report(pushed)
    return pushed.sha


def _dataset_info(root: Path) -> dict:
    """``meta/info.json`` of dataset ``root``, which has a codebase version and no symbolic
    link (refused before anything else is read)."""
    info_path = L.info_path(root)
    if not info_path.is_file():
        raise FileNotFoundError(f"{root} is not a LeRobot dataset root: {info_path} is missing")
    _local_files(root, "dataset")
    info = json.loads(info_path.read_text())
    version = info.get("codebase_version")
    if not isinstance(version, str) or not version:
        raise HubError(f"{info_path} has no 'codebase_version'")
    return info


def push_dataset(root: str | os.PathLike, repo_id: str, private: bool = False, *,
                 card: CardInfo | None = None, tag: str | None = None, message: str | None = None,
                 endpoint: str | None = None, token: str | bool | None = None,
                 report: Callable[[Pushed], None] | None = None) -> str:
    """Push a LeRobot dataset root to a dataset repo and tag it with its codebase version.

    The dataset is locked (no writer may append meanwhile) and verified first
    (``msta.data.integrity.verify_for_publish``: every committed file against the size and
    sha256 recorded at commit, no leftover of an unfinished commit); a bad file, or a symbolic
    link under ``root`` (``PathOutsideRootError``), is an error naming it, nothing uploaded.

    The codebase-version tag (e.g. ``v3.0``) is moved to the new commit, as LeRobot's own push
    does, so ``LeRobotDataset(repo_id, revision="v3.0")`` loads the latest push; ``tag`` marks
    this particular version and is never moved.

    Args:
        root: dataset root holding meta/info.json.
        repo_id: ``user/name`` of the dataset repo.
        private: create the repo as private.
        card: dataset card content; default: what msta's card in the root records (none
            when the root has no README.md). Either way the card is rebuilt from the files
            pushed (``hub_cards.root_dataset_card``: sizes, provenance counts, features), so
            a dataset pulled, appended to and pushed again says its true counts; a README.md
            of the user's own (no ``msta`` block) is kept unless ``card`` is given.
        tag: extra tag for this version.
        message: commit message; default ``Upload LeRobot dataset <name> (<e> episodes, ...)``.
        endpoint: hub URL (default HF_ENDPOINT).
        token: secret (default HF_TOKEN).
        report: called with the :class:`Pushed` (the commit's URL, what it holds).

    Returns the commit sha.
    """
    root = Path(root)
    info = _dataset_info(root)
    version = info["codebase_version"]
    try:  # no writer may append meanwhile
        lock: int | None = lock_directory(root, "a dataset writer", DatasetLockedError)
    except PermissionError:  # a read-only copy: nobody appends to it through msta
        lock = None
    try:
        verify_for_publish(root)  # refuses, naming the file, before anything is uploaded
        api = hub_api(endpoint, token)
        text = root_dataset_card(root, card, repo_id)  # None: the user's own README.md
        files = _local_files(root, "dataset")
        title = (f"Upload LeRobot dataset {root.name} ({info.get('total_episodes')} episodes, "
                 f"{_count(files, text)} files)")
        pushed = _commit_dir(api, root, files, repo_id, "dataset", branch="main",
                             private=private, card_text=text, allow_pickle=False,
                             message=message or title)
    finally:
        if lock is not None:
            os.close(lock)
    sha = pushed.sha
    _set_tag(api, repo_id, "dataset", version, sha, move=True)
    if tag:
        _set_tag(api, repo_id, "dataset", tag, sha, move=False)
    logger.info("pushed dataset %s to %s (commit %s, tag %s)", root, repo_id, sha[:12], version)
    if report is not None:
        report(replace(pushed, ref=f"datasets/{repo_id}@{version}"))
    return sha

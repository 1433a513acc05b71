"""Resolve a hub id to a commit, pull it verified and all-or-nothing, and materialize
checkpoints and datasets in a per-commit cache.

Pulls resolve the revision to one commit, download into a temporary directory next to the
destination, check every file against the hub's hashes (sha256 for LFS files, the git blob
sha1 otherwise) and only then rename the directory into place. Nothing here unpickles.
"""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
from pathlib import Path

from huggingface_hub import HfApi
from huggingface_hub.errors import RepositoryNotFoundError, RevisionNotFoundError

from msta.data.hub_ids import HubError, HubId, HubIntegrityError, hub_api, parse_hub_id
from msta.data.layout import hf_home

logger = logging.getLogger(__name__)


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
    """Where ``materialize`` keeps pulled commits: ``MSTA_HUB_CACHE`` when set, else
    ``<HF_HOME>/msta/hub`` beside LeRobot's ``<HF_HOME>/lerobot`` (:func:`hf_home`; read when
    called, so setting HF_HOME moves every Hugging Face and msta cache at once)."""
    own = os.environ.get("MSTA_HUB_CACHE")
    return Path(os.path.expandvars(os.path.expanduser(own))) if own else hf_home() / "msta" / "hub"


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

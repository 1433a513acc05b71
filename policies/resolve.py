"""Path or hub id -> a local msta checkpoint directory: msta's one resolver for students.

A local directory is taken as it is; a hub id ``user/name[@revision]`` is pulled once per
commit, hash-verified (:func:`msta.data.locate.locate_checkpoint`, the one path-or-hub-id
rule); a LeRobot checkpoint of the MSTA student becomes the msta checkpoint made from it
(:func:`msta.policies.lerobot_checkpoint.as_msta_checkpoint`).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from msta.policies.lerobot_checkpoint import as_msta_checkpoint


def resolve_pretrained(path_or_repo_id: str | Path, revision: str | None = None, *,
                       policy_class: Callable[[str], Any], what: str = "checkpoint") -> Path:
    """A local msta checkpoint directory for ``path_or_repo_id``.

    Args:
        path_or_repo_id: a local directory, or a hub id ``user/name[@revision]`` pulled
            (once per commit, hash-verified) from ``HF_ENDPOINT``.
        revision: hub revision (branch, tag or commit) when the id carries none.
        policy_class: policy name -> the student class that reads a LeRobot checkpoint
            (:func:`msta.policies.registry.get_policy_class`).
        what: the option or argument the path came from, for messages (``--policy.path``).

    Returns:
        the directory; for a LeRobot msta checkpoint, an msta checkpoint made from it.

    Raises:
        FileNotFoundError: no such directory, or a file (path named).
        CheckpointError: a LeRobot checkpoint of another policy type, or a malformed one.
    """
    # lazy: the hub client loads when a checkpoint is resolved, not with every student
    from msta.data.locate import locate_checkpoint

    return as_msta_checkpoint(locate_checkpoint(str(path_or_repo_id), what, revision),
                              policy_class)

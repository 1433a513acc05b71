"""Hub server commit storage (issue 15, defect 5): size linear in the changes, every revision
reads back exactly, and roots written by the previous storage format keep working."""

from __future__ import annotations

import hashlib
import json
import random
from pathlib import Path

import msta_hub_security_helpers as H  # registered by tests/conftest.py
from huggingface_hub import HfApi

ALICE = H.ALICE


def _metadata_bytes(repo_dir: Path) -> int:
    return sum(p.stat().st_size for sub in ("commits", "trees") for p in (repo_dir / sub).glob("*.json"))


def test_commit_metadata_grows_linearly_and_every_revision_reads_back(tmp_path):
    """400 commits adding, changing and deleting files: metadata stays O(changes), not
    O(commits x files) as with a full file table per commit, and each revision is exact."""
    srv = H.start_server(tmp_path / "hub")
    try:
        H.create_repo(srv, ALICE, "grow")
        repo_dir = srv.config.root / "repos" / "models" / "alice" / "grow"
        rng = random.Random(0)
        expected: dict[str, dict[str, str]] = {}  # commit -> {path: git blob id}
        files: dict[str, str] = {}
        sizes = {}
        for i in range(400):
            older = sorted(files)
            ops = [H.inline_file(f"data/f{i:04d}.txt", b"%d" % i)]
            files[f"data/f{i:04d}.txt"] = H.git_sha1(b"%d" % i)
            if i % 7 == 3:  # modify an older file
                victim = older.pop(rng.randrange(len(older)))
                ops.append(H.inline_file(victim, b"changed %d" % i))
                files[victim] = H.git_sha1(b"changed %d" % i)
            if i % 11 == 5:  # delete another one
                victim = older.pop(rng.randrange(len(older)))
                ops.append({"key": "deletedFile", "value": {"path": victim}})
                del files[victim]
            status, body = H.commit(srv, ALICE, "alice/grow", ops, summary=f"c{i}")
            assert status == 200, body
            expected[json.loads(body)["commitOid"]] = dict(files)
            if i + 1 in (200, 400):
                sizes[i + 1] = _metadata_bytes(repo_dir)
        # a full table per commit would be ~ sum(n) x 130 bytes = 9.5 MB here
        assert sizes[400] < 1_500_000, sizes
        assert sizes[400] < 2.6 * sizes[200], sizes  # linear: ~2x for 2x the commits (quadratic: ~4x)
        api = HfApi(endpoint=srv.url, token=ALICE)
        commits = [c.commit_id for c in api.list_repo_commits("alice/grow")]
        assert len(commits) == 401 and set(commits[:-1]) == set(expected)
        for sha in rng.sample(sorted(expected), 25) + commits[:3]:
            tree = {e.path: e.blob_id for e in api.list_repo_tree("alice/grow", revision=sha, recursive=True)
                    if e.path.startswith("data/")}
            assert tree == expected[sha], sha
        last = {e.path: e.last_commit.title for e in api.list_repo_tree("alice/grow", "data", expand=True)}
        assert last["data/f0399.txt"] == "c399" and last["data/f0000.txt"] in {f"c{i}" for i in range(400)}
    finally:
        srv.stop()


def _legacy_root(root: Path) -> tuple[str, str, bytes]:
    """A root as the format-1 server wrote it: full file table in each commit, no blobs.txt."""
    content = b"legacy weights"
    sha256 = hashlib.sha256(content).hexdigest()
    (root / "blobs" / sha256[:2]).mkdir(parents=True)
    (root / "blobs" / sha256[:2] / sha256).write_bytes(content)
    (root / "tmp").mkdir()
    (root / "FORMAT").write_text("msta-hub-storage 1\n")
    repo = root / "repos" / "models" / "alice" / "old"
    (repo / "commits").mkdir(parents=True)
    c0, c1 = "0" * 39 + "1", "0" * 39 + "2"
    entry = {"sha256": sha256, "size": len(content), "oid": hashlib.sha1(b"x").hexdigest(), "lfs": True}
    meta = {"title": "t", "message": "", "author": "alice", "date": "2024-01-01T00:00:00.000Z"}
    (repo / "commits" / f"{c0}.json").write_text(json.dumps({"id": c0, "parents": [], "files": {}, **meta}))
    (repo / "commits" / f"{c1}.json").write_text(json.dumps(
        {"id": c1, "parents": [c0], "files": {"w.bin": entry}, **meta}))
    (repo / "refs.json").write_text(json.dumps({"branches": {"main": c1}, "tags": {"v1": c1}}))
    (repo / "repo.json").write_text(json.dumps({"id": "alice/old", "type": "model", "private": True,
                                                "createdAt": "2024-01-01T00:00:00.000Z"}))
    return c1, sha256, content


def test_format_1_roots_stay_readable_and_writable(tmp_path):
    c1, sha256, content = _legacy_root(tmp_path / "hub")
    srv = H.start_server(tmp_path / "hub")
    try:
        api = HfApi(endpoint=srv.url, token=ALICE)
        assert api.model_info("alice/old", revision="v1").sha == c1
        assert H.call(srv, "GET", "/alice/old/resolve/v1/w.bin", token=ALICE)[1] == content
        # the repo's own blob may be referenced again (blobs.txt rebuilt from its commits)
        status, body = H.commit(srv, ALICE, "alice/old", [H.lfs_file("copy.bin", sha256)])
        assert status == 200, body
        assert sorted(api.list_repo_files("alice/old")) == ["copy.bin", "w.bin"]
        assert [c.commit_id for c in api.list_repo_commits("alice/old")][1] == c1
        last = {e.path: e.last_commit.oid for e in api.list_repo_tree("alice/old", expand=True)}
        assert last["w.bin"] == c1
    finally:
        srv.stop()
    assert (tmp_path / "hub" / "FORMAT").read_text().strip() == "msta-hub-storage 3"

"""Regression tests for the hub server's security defects of issue 15 (docs/security.md).

Each test drives a real server on 127.0.0.1 over HTTP (raw requests where the attack needs
bytes huggingface_hub would never send, the real huggingface_hub client elsewhere).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import time
from pathlib import Path

import msta_hub_security_helpers as H  # registered by tests/conftest.py
import pytest
from huggingface_hub import HfApi

ALICE, BOB = H.ALICE, H.BOB
CANARY = b"CANARY-" + os.urandom(12).hex().encode()


@pytest.fixture
def hub(tmp_path):
    """(server, canary path): the root is tmp_path/hub, a secret file sits next to it."""
    canary = tmp_path / "canary.txt"
    canary.write_bytes(CANARY)
    srv = H.start_server(tmp_path / "hub", read_timeout_s=2.0)
    H.create_repo(srv, BOB, "mine")
    yield srv, canary
    srv.stop()


def _traversal_oids(canary: Path) -> list[str]:
    rel = ["../canary.txt", "../../canary.txt", "../../../canary.txt"]
    return [
        "../../../../../../../../etc/passwd",  # the auditor's reproduction
        *rel,
        str(canary),  # absolute path
        "%2e%2e/%2e%2e/canary.txt",  # percent-encoded dots
        "..%2f..%2fcanary.txt",  # percent-encoded slash
        "..\\..\\canary.txt",  # backslashes
        "/etc/passwd",
        "ab/../../canary.txt",
        "../" * 20 + "etc/passwd",
        hashlib.sha256(CANARY).hexdigest().upper(),  # right hash, wrong spelling
        hashlib.sha256(CANARY).hexdigest() + "/../../canary.txt",
        "",
    ]


# ------------------------------------------------------------------ 1: path traversal
def test_lfs_oid_traversal_is_refused_in_every_encoding(hub):
    srv, canary = hub
    for oid in _traversal_oids(canary):
        for size in (None, 0, len(CANARY)):
            status, body = H.commit(srv, BOB, "bob/mine", [H.lfs_file("p.txt", oid, size)])
            assert status == 400, (oid, status, body)
            assert CANARY not in body and b"root:" not in body
        status, body, _ = H.call(srv, "GET", "/bob/mine/resolve/main/p.txt", token=BOB)
        assert status == 404 and CANARY not in body and b"root:" not in body
    assert H.call(srv, "GET", "/api/models/bob/mine/tree/main", token=BOB)[1] == b"[]"


def test_traversal_through_urls_and_commit_paths_is_refused(hub):
    srv, canary = hub
    assert H.commit(srv, BOB, "bob/mine", [H.inline_file("ok.txt", b"ok")])[0] == 200
    for path in ("../../canary.txt", "..%2f..%2fcanary.txt", "%2e%2e/%2e%2e/canary.txt",
                 "ok.txt/../../../canary.txt", "..%5c..%5ccanary.txt", "%2Ftmp%2Fcanary.txt",
                 canary.as_posix().lstrip("/"), "ok.txt%00.png"):
        for url in (f"/bob/mine/resolve/main/{path}", f"/api/models/bob/mine/tree/main/{path}",
                    f"/bob/mine/resolve/{path}/ok.txt", f"/api/models/bob/mine/revision/{path}"):
            status, body, _ = H.call(srv, "GET", url, token=BOB)
            assert status in (400, 404), (url, status)
            assert CANARY not in body
    for bad in ("../x", "a/../../x", "/abs", "a\\..\\x", "a//b", ".git/config", "a/./b", "x\x00y", ""):
        for op in (H.inline_file(bad, b"x"), {"key": "deletedFile", "value": {"path": bad}}):
            status, body = H.commit(srv, BOB, "bob/mine", [op])
            assert status == 400, (bad, op["key"], status, body)
    assert not list((srv.config.root.parent).glob("x*"))  # nothing written outside the root


# ------------------------------------------------------------------ 2: blobs stay in their repo
def test_a_known_hash_does_not_open_another_repos_blob(hub):
    srv, _ = hub
    H.create_repo(srv, ALICE, "vault", private=True)
    secret_inline, secret_lfs = b"alice inline secret " + os.urandom(8), b"alice lfs secret " + os.urandom(8)
    assert H.commit(srv, ALICE, "alice/vault", [H.inline_file("a.txt", secret_inline)])[0] == 200
    assert H.lfs_upload(srv, ALICE, "alice/vault", secret_lfs) == 200
    assert H.commit(srv, ALICE, "alice/vault", [H.lfs_file("b.bin", hashlib.sha256(secret_lfs).hexdigest())])[0] == 200
    never_stored = hashlib.sha256(b"never uploaded anywhere").hexdigest()
    for secret in (secret_inline, secret_lfs):
        oid = hashlib.sha256(secret).hexdigest()
        status, body = H.commit(srv, BOB, "bob/mine", [H.lfs_file("stolen.bin", oid, len(secret))])
        assert status == 400 and b"not uploaded to this repo" in body
        assert H.call(srv, "GET", "/bob/mine/resolve/main/stolen.bin", token=BOB)[0] == 404
        # the batch answer for alice's object looks exactly like the one for an unknown object
        known, unknown = H.lfs_batch(srv, BOB, "bob/mine", oid, len(secret)), H.lfs_batch(
            srv, BOB, "bob/mine", never_stored, len(secret))
        assert set(known) == set(unknown) == {"oid", "size", "authenticated", "actions"}
        # claiming the hash with other bytes fails; holding the bytes really is enough
        assert H.lfs_upload(srv, BOB, "bob/mine", os.urandom(len(secret)), claimed_oid=oid) == 400
        assert H.commit(srv, BOB, "bob/mine", [H.lfs_file("stolen.bin", oid)])[0] == 400
    # alice's own other repo cannot reference it by hash either: blobs belong to a repo
    H.create_repo(srv, ALICE, "other")
    assert H.commit(srv, ALICE, "alice/other", [H.lfs_file("c.bin", hashlib.sha256(secret_lfs).hexdigest())])[0] == 400
    assert H.lfs_upload(srv, BOB, "bob/mine", secret_lfs) == 200  # bob really has the bytes
    assert H.commit(srv, BOB, "bob/mine", [H.lfs_file("own.bin", hashlib.sha256(secret_lfs).hexdigest())])[0] == 200
    assert H.call(srv, "GET", "/bob/mine/resolve/main/own.bin", token=BOB)[1] == secret_lfs


# ------------------------------------------------------------------ 3: YAML alias bomb
def _alias_bomb(levels: int = 9) -> bytes:
    lines = ['a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    names = "abcdefghijklmnop"
    for prev, name in itertools.pairwise(names[:levels]):
        lines.append(f"{name}: &{name} [" + ",".join([f"*{prev}"] * 9) + "]")
    return ("---\n" + "\n".join(lines) + "\n---\n# card\n").encode()


def test_yaml_alias_bomb_is_refused_and_never_expanded(hub):
    srv, _ = hub
    bomb = _alias_bomb()
    assert len(bomb) < 600
    status, body, _ = H.call(srv, "POST", "/api/validate-yaml", json.dumps(
        {"content": bomb.decode(), "repoType": "model"}), BOB)
    assert status == 400 and b"more than 100000 nodes once its aliases" in body  # counted, never built
    small = _alias_bomb(levels=5)  # 9**5 nodes: few enough to build, too large once expanded
    status, body, _ = H.call(srv, "POST", "/api/validate-yaml", json.dumps(
        {"content": small.decode(), "repoType": "model"}), BOB)
    assert status == 400 and b"expands to more than" in body
    # a raw commit skips validate-yaml: the anonymous model info must stay small anyway
    assert H.commit(srv, BOB, "bob/mine", [H.inline_file("README.md", bomb)])[0] == 200
    t0 = time.monotonic()
    status, body, _ = H.call(srv, "GET", "/api/models/bob/mine")
    assert status == 200 and len(body) < 4096 and time.monotonic() - t0 < 5
    assert "cardData" not in json.loads(body)
    cyclic = b"---\na: &a [*a]\nb: 2024-01-01\n---\n"
    assert H.commit(srv, BOB, "bob/mine", [H.inline_file("README.md", cyclic)])[0] == 200
    assert H.call(srv, "GET", "/api/models/bob/mine")[0] == 200
    dated = b"---\ntags: mytag\ndate: 2024-01-01\nscore: .nan\n---\n"
    assert H.commit(srv, BOB, "bob/mine", [H.inline_file("README.md", dated)])[0] == 200
    info = HfApi(endpoint=srv.url, token=False).model_info("bob/mine")
    assert info.card_data["date"] == "2024-01-01" and info.tags == ["mytag"]


def test_yaml_merge_key_bomb_is_counted_before_it_is_built(hub):
    """Each level merges the previous one twice: 2**40 nodes once expanded. The server counts
    merges as expansions before building anything, whatever the PyYAML version does with them."""
    srv, _ = hub
    levels = "".join(f"l{i}: &l{i} {{<<: [*l{i - 1}, *l{i - 1}]}}\n" for i in range(1, 41))
    bomb = f"---\nl0: &l0 {{x: 1}}\n{levels}---\n# card\n"
    t0 = time.monotonic()
    status, body, _ = H.call(srv, "POST", "/api/validate-yaml", json.dumps({"content": bomb}))
    assert status == 400 and b"nodes once its aliases and merge keys are expanded" in body, body
    assert time.monotonic() - t0 < 5
    assert H.commit(srv, BOB, "bob/mine", [H.inline_file("README.md", bomb.encode())])[0] == 200
    status, body, _ = H.call(srv, "GET", "/api/models/bob/mine")
    assert status == 200 and "cardData" not in json.loads(body)
    merged = "---\nbase: &base {license: mit}\nmodel: {<<: *base, tags: [a]}\n---\n"
    assert H.call(srv, "POST", "/api/validate-yaml", json.dumps({"content": merged}))[0] == 200

"""Regression tests for the hub server defects of issue 41 part A2 (docs/security.md):
short shas that a ref could hijack, reusable LFS tickets, and batch and tree listings whose
cost grew with the square of their size.

Every test drives a real server on 127.0.0.1 over HTTP. Cost tests compare the CPU time of
the same request at sizes n and 8n in one run (CPU time of this process, which hosts the
server threads, so other processes on a loaded machine do not inflate it, with the garbage
collector paused): linear work measures 4-8, the quadratic work it replaced about 100; the
bound is 20.
"""

from __future__ import annotations

import gc
import hashlib
import json
import socket
import subprocess
import time
from collections.abc import Callable
from urllib.parse import urlencode, urlsplit

import msta_hub_security_helpers as H  # registered by tests/conftest.py
import pytest
from huggingface_hub import HfApi
from huggingface_hub.errors import HfHubHTTPError

from msta.data.hub_pull import pull

ALICE = H.ALICE
LINEAR_BOUND = 20.0


@pytest.fixture
def srv(tmp_path):
    server = H.start_server(tmp_path / "hub")
    yield server
    server.stop()


def _cpu_seconds(fn: Callable[[], None]) -> float:
    """CPU time of ``fn`` with the garbage collector paused (as timeit does: a collection of
    the whole heap landing in one run would weigh more than the request itself)."""
    gc.collect()
    gc.disable()
    try:
        t0 = time.process_time()
        fn()
        return time.process_time() - t0
    finally:
        gc.enable()


def _cost_ratio(small: Callable[[], None], big: Callable[[], None], tries: int = 3) -> float:
    """min CPU time of ``big`` / min CPU time of ``small`` (stops early once under the bound)."""
    best_small = best_big = float("inf")
    for _ in range(tries):
        best_small = min(best_small, _cpu_seconds(small))
        best_big = min(best_big, _cpu_seconds(big))
        if best_big / max(best_small, 1e-3) < LINEAR_BOUND:
            break
    return best_big / max(best_small, 1e-3)


# ------------------------------------------------------------------ 3: short shas and refs
def _pulled(tmp_path, spec: str, name: str) -> bytes:
    return (pull(spec, tmp_path / name) / "x.txt").read_bytes()


def test_a_ref_named_like_a_short_sha_never_hijacks_the_commit(srv, tmp_path, monkeypatch):
    monkeypatch.setenv("HF_ENDPOINT", srv.url)
    monkeypatch.setenv("HF_TOKEN", ALICE)
    H.create_repo(srv, ALICE, "m")
    assert H.commit(srv, ALICE, "alice/m", [H.inline_file("x.txt", b"pinned")])[0] == 200
    api = HfApi(endpoint=srv.url, token=ALICE)
    old = api.list_repo_commits("alice/m")[0].commit_id
    assert H.commit(srv, ALICE, "alice/m", [H.inline_file("x.txt", b"attacker")])[0] == 200
    for name in (old[:7], old[:12], old[:39], "deadbeef", "0123456"):
        for create in (lambda n: api.create_branch("alice/m", branch=n),
                       lambda n: api.create_tag("alice/m", tag=n)):
            with pytest.raises(HfHubHTTPError) as err:
                create(name)
            assert err.value.response.status_code == 400 and "hex" in str(err.value)
    assert _pulled(tmp_path, f"alice/m@{old[:7]}", "a") == b"pinned"
    # refs of an older root (or written by hand) that read as a sha: the commit wins for a
    # full sha, and a short sha that names both a ref and a commit is refused
    refs_path = tmp_path / "hub" / "repos" / "models" / "alice" / "m" / "refs.json"
    refs = json.loads(refs_path.read_text())
    head = refs["branches"]["main"]
    refs["branches"].update({old[:7]: head, old: head})
    refs["tags"][old[:10]] = head
    refs_path.write_text(json.dumps(refs))
    assert _pulled(tmp_path, f"alice/m@{old}", "b") == b"pinned"
    for short in (old[:7], old[:10]):
        with pytest.raises(HfHubHTTPError) as err:
            pull(f"alice/m@{short}", tmp_path / f"c{short}")
        assert err.value.response.status_code == 400 and "ambiguous" in str(err.value)
        assert not (tmp_path / f"c{short}").exists()
    assert _pulled(tmp_path, f"alice/m@refs/heads/{old[:7]}", "d") == b"attacker"  # named as a ref


# ------------------------------------------------------------------ 4: LFS tickets and batch
def _put_and_verify(srv, obj: dict, data: bytes) -> tuple[int, int]:
    put = urlsplit(obj["actions"]["upload"]["href"]).path
    verify = urlsplit(obj["actions"]["verify"]["href"]).path
    status = H.call(srv, "PUT", put, data)[0]
    vstatus = H.call(srv, "POST", verify, json.dumps({"oid": obj["oid"], "size": len(data)}), ALICE)[0]
    return status, vstatus


def test_lfs_upload_tickets_are_one_time(srv):
    H.create_repo(srv, ALICE, "m")
    data = b"large file " * 100
    oid = hashlib.sha256(data).hexdigest()
    obj = H.lfs_batch(srv, ALICE, "alice/m", oid, len(data))
    put = urlsplit(obj["actions"]["upload"]["href"]).path
    wrong = bytes(reversed(data))
    assert H.call(srv, "PUT", put, wrong)[0] == 400  # a failed upload leaves the ticket usable
    assert H.call(srv, "PUT", put, data)[0] == 200
    for body in (data, wrong):  # used: refused, also with the same bytes
        status, answer, _ = H.call(srv, "PUT", put, body)
        assert status == 403 and b"already used" in answer, (status, answer)
    assert _put_and_verify(srv, obj, data) == (403, 200)  # verify still closes the upload
    assert _put_and_verify(srv, obj, data) == (403, 403)  # and then the ticket is gone
    assert H.commit(srv, ALICE, "alice/m", [H.lfs_file("big.bin", oid, len(data))])[0] == 200


def test_an_lfs_ticket_in_use_is_refused_to_a_second_upload(srv):
    H.create_repo(srv, ALICE, "m")
    data = b"uploaded slowly " * 64
    obj = H.lfs_batch(srv, ALICE, "alice/m", hashlib.sha256(data).hexdigest(), len(data))
    put = urlsplit(obj["actions"]["upload"]["href"]).path
    with socket.create_connection(("127.0.0.1", srv.port), timeout=10) as first:
        first.sendall(f"PUT {put} HTTP/1.1\r\nHost: x\r\nContent-Length: {len(data)}\r\n\r\n".encode()
                      + data[:10])
        # The second PUT goes out once the first holds the ticket: sent earlier, the second
        # would hold it and the first be the one refused.
        deadline = time.monotonic() + 30
        while not srv.app.tickets.used(put.rsplit("/", 1)[1]):
            assert time.monotonic() < deadline, "the first upload never took its ticket"
            time.sleep(0.01)
        status, answer, _ = H.call(srv, "PUT", put, data)
        assert status == 403 and b"already used" in answer, (status, answer)
        first.sendall(data[10:])
        assert first.recv(100).startswith(b"HTTP/1.1 200")
    assert H.call(srv, "PUT", put, data)[0] == 403  # the first upload used it up


def test_lfs_batch_cost_is_linear_in_the_number_of_objects(srv):
    H.create_repo(srv, ALICE, "m")

    def batch(n: int) -> Callable[[], None]:
        objects = [{"oid": hashlib.sha256(b"%d-%d" % (n, i)).hexdigest(), "size": i} for i in range(n)]
        body = json.dumps({"operation": "upload", "transfers": ["basic"], "objects": objects})

        def run() -> None:
            status, answer, _ = H.call(srv, "POST", "/alice/m.git/info/lfs/objects/batch", body, ALICE,
                                       {"Content-Type": "application/vnd.git-lfs+json"})
            assert status == 200 and answer.count(b'"upload"') == n
        return run

    ratio = _cost_ratio(batch(125), batch(1000))  # 1000: the most one batch may list
    assert ratio < LINEAR_BOUND, f"8x the objects cost {ratio:.0f}x the CPU time"


# ------------------------------------------------------------------ 5: tree and paths-info
def _one_file_dirs(srv, repo: str, n: int) -> None:
    H.create_repo(srv, ALICE, repo)
    ops = [H.inline_file(f"d{i:05d}/f.txt", b"same bytes") for i in range(n)]
    assert H.commit(srv, ALICE, f"alice/{repo}", ops)[0] == 200


@pytest.mark.parametrize("listing", ["tree", "tree_recursive", "paths_info"])
def test_tree_and_paths_info_cost_is_linear_in_the_number_of_directories(srv, listing):
    sizes = {"small": 500, "big": 4000}
    for repo, n in sizes.items():
        _one_file_dirs(srv, repo, n)

    def request(repo: str) -> Callable[[], None]:
        n = sizes[repo]
        form = urlencode([("paths", f"d{i:05d}") for i in range(n)])

        def run() -> None:
            if listing == "paths_info":
                status, answer, _ = H.call(srv, "POST", f"/api/models/alice/{repo}/paths-info/main", form,
                                           headers={"Content-Type": "application/x-www-form-urlencoded"})
            else:
                query = "?recursive=true" if listing == "tree_recursive" else ""
                status, answer, _ = H.call(srv, "GET", f"/api/models/alice/{repo}/tree/main{query}")
            assert status == 200 and answer.count(b'"directory"') == n
        return run

    ratio = _cost_ratio(request("small"), request("big"))
    assert ratio < LINEAR_BOUND, f"8x the directories cost {ratio:.0f}x the CPU time"


def test_directory_oids_are_git_tree_ids(srv, tmp_path):
    """A directory's oid is what git computes for the same files (``git rev-parse HEAD:dir``),
    including git's order (a directory ``a`` sorts as ``a/``, after ``a-b``)."""
    files = {"a/x.txt": b"1", "a-b": b"2", "a.txt": b"3", "a/b/c/deep.txt": b"4", "a/b/z": b"5",
             "b/a-b/y": b"6", "b/a/y": b"7", "b/a.y": b"8"}
    H.create_repo(srv, ALICE, "g")
    assert H.commit(srv, ALICE, "alice/g", [H.inline_file(p, d) for p, d in files.items()])[0] == 200
    status, answer, _ = H.call(srv, "GET", "/api/models/alice/g/tree/main?recursive=true")
    dirs = {e["path"]: e["oid"] for e in json.loads(answer) if e["type"] == "directory"}
    assert status == 200 and set(dirs) == {"a", "a/b", "a/b/c", "b", "b/a", "b/a-b"}
    work = tmp_path / "git"
    for rel, data in files.items():
        (work / rel).parent.mkdir(parents=True, exist_ok=True)
        (work / rel).write_bytes(data)
    git = ["git", "-C", str(work), "-c", "user.name=t", "-c", "user.email=t@t"]
    for args in (["init", "-q"], ["add", "-A"], ["commit", "-qm", "x"]):
        subprocess.run([*git, *args], check=True, capture_output=True)
    for path, oid in dirs.items():
        expected = subprocess.run([*git, "rev-parse", f"HEAD:{path}"], check=True, capture_output=True,
                                  text=True).stdout.strip()
        assert oid == expected, path
    form = urlencode([("paths", "b/a"), ("paths", "nope"), ("paths", "a.txt")])
    status, answer, _ = H.call(srv, "POST", "/api/models/alice/g/paths-info/main", form,
                               headers={"Content-Type": "application/x-www-form-urlencoded"})
    assert [(e["path"], e["oid"]) for e in json.loads(answer)] == [("b/a", dirs["b/a"]),
                                                                    ("a.txt", H.git_sha1(b"3"))]

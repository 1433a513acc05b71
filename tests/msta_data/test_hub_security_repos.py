"""What a repo holds and how it is named, against a real hub server on 127.0.0.1 (issue
harden-3; docs/security.md): paths must be text and cannot be a file and a folder at once;
each repo stores its own contents, so a write does the same work whether or not another
(private) repo holds the same bytes; repo ids are case-insensitive, as on the Hugging Face hub.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import sys
from urllib.parse import urlsplit

import msta_hub_security_helpers as H  # registered by tests/conftest.py
import pytest
from huggingface_hub import HfApi
from huggingface_hub.errors import HfHubHTTPError

ALICE, BOB = H.ALICE, H.BOB


@pytest.fixture
def srv(tmp_path):
    server = H.start_server(tmp_path / "hub")
    yield server
    server.stop()


# ------------------------------------------------------------------ paths
@pytest.mark.parametrize("path", ["\udc80", "data/\ud800.bin", "a\udfffb/c.txt"])
def test_a_path_with_a_lone_surrogate_is_refused_and_listings_keep_working(srv, path):
    """JSON lets a client send "\\udc80", which is no text: the commit is 400 with one line,
    and the repo's tree and paths-info still answer."""
    H.create_repo(srv, ALICE, "m")
    status, body = H.commit(srv, ALICE, "alice/m", [H.inline_file(path, b"x"), H.inline_file("ok.txt", b"y")])
    message = json.loads(body)["error"]
    assert status == 400 and "not valid UTF-8 text" in message and "\n" not in message, body
    assert H.call(srv, "GET", "/api/models/alice/m/tree/main?recursive=true", token=ALICE)[:2] == (200, b"[]")
    status, body, _ = H.call(srv, "POST", "/api/models/alice/m/paths-info/main",
                             json.dumps({"paths": ["ok.txt"]}), ALICE, {"Content-Type": "application/json"})
    assert (status, body) == (200, b"[]")


def test_a_file_and_a_folder_at_one_path_are_refused(srv):
    """``a`` beside ``a/x``: 400 within one commit, 409 against the branch (either order);
    replacing one by the other in one commit (delete, then add) works."""
    H.create_repo(srv, ALICE, "m")
    put = H.inline_file
    status, body = H.commit(srv, ALICE, "alice/m", [put("a", b"1"), put("a/x", b"2")])
    assert status == 400 and "a path cannot be a file and a folder" in body.decode(), body
    assert H.commit(srv, ALICE, "alice/m", [put("d/a/x", b"2")])[0] == 200
    for path in ("d/a", "d"):  # a file where a folder is
        status, body = H.commit(srv, ALICE, "alice/m", [put(path, b"1")])
        assert status == 409 and "'d/a/x' is on branch main" in body.decode(), body
    status, body = H.commit(srv, ALICE, "alice/m", [put("d/a/x/y", b"3")])  # a folder under a file
    assert status == 409 and "'d/a/x' is on branch main" in body.decode(), body
    ops = [{"key": "deletedFolder", "value": {"path": "d/a/"}}, put("d/a", b"now a file")]
    assert H.commit(srv, ALICE, "alice/m", ops)[0] == 200
    ops = [{"key": "deletedFile", "value": {"path": "d/a"}}, put("d/a/z", b"a folder again")]
    assert H.commit(srv, ALICE, "alice/m", ops)[0] == 200
    files = sorted(HfApi(endpoint=srv.url, token=ALICE).list_repo_files("alice/m"))
    assert files == ["d/a/z"]


# ------------------------------------------------------------------ one content store per repo
_WATCH: dict[str, str] = {}
_EVENTS: list[tuple[str, ...]] = []
_WRITE_FLAGS = os.O_WRONLY | os.O_RDWR | os.O_APPEND | os.O_CREAT


def _shape(path: object) -> str:
    """A path under the watched root with every run of hex digits written as H (hashes and
    random names differ between two uploads of different bytes; the shape does not)."""
    return re.sub(r"[0-9a-f]{2,}", "H", os.fsdecode(path)[len(_WATCH["root"]):])


def _audit(event: str, args: tuple) -> None:
    """Record every write, rename, removal and mkdir under the watched root."""
    root = _WATCH.get("root")
    if root is None or event not in ("open", "os.rename", "os.remove", "os.mkdir"):
        return
    if not isinstance(args[0], (str, bytes, os.PathLike)) or not os.fsdecode(args[0]).startswith(root):
        return
    if event == "open":
        mode, flags = args[1], args[2]
        if not (any(c in (mode or "") for c in "wax+") or (mode is None and flags & _WRITE_FLAGS)):
            return  # reads are the same whatever other repos hold
    _EVENTS.append((event, *(_shape(a) for a in args[:2 if event == "os.rename" else 1])))


sys.addaudithook(_audit)  # audit hooks cannot be removed; _audit does nothing unless watching


def _writes(srv, action) -> list[tuple[str, ...]]:
    """The file-system writes (event, path shape) the server does while ``action`` runs."""
    _EVENTS.clear()
    _WATCH["root"] = str(srv.config.root)
    try:
        action()
    finally:
        _WATCH.clear()
    return list(_EVENTS)


def test_bytes_another_private_repo_holds_are_written_in_full_like_new_ones(srv):
    """No timing oracle across repos: committing (inline) or uploading (LFS) bytes that bob
    holds in a private repo does exactly the file-system writes that new bytes of the same
    size cause, and lands in alice's own store, a file of its own."""
    H.create_repo(srv, BOB, "secret", private=True)
    H.create_repo(srv, ALICE, "probe")
    known_inline, known_lfs = b"bob's private weights " * 100, os.urandom(5000)
    assert H.commit(srv, BOB, "bob/secret", [H.inline_file("w.txt", known_inline)])[0] == 200
    assert H.lfs_upload(srv, BOB, "bob/secret", known_lfs) == 200

    def inline(data: bytes, path: str):
        return lambda: H.commit(srv, ALICE, "alice/probe", [H.inline_file(path, data)])

    assert len(_writes(srv, inline(b"first", "first.txt"))) >= 4  # blob, commit, refs, blobs.txt
    fresh = bytes(reversed(known_inline))
    assert _writes(srv, inline(known_inline, "k.txt")) == _writes(srv, inline(fresh, "f.txt"))

    def upload(data: bytes):
        obj = H.lfs_batch(srv, ALICE, "alice/probe", hashlib.sha256(data).hexdigest(), len(data))
        return lambda: H.call(srv, "PUT", urlsplit(obj["actions"]["upload"]["href"]).path, data)

    assert _writes(srv, upload(known_lfs)) == _writes(srv, upload(os.urandom(5000)))
    repos = srv.config.root / "repos" / "models"
    for data in (known_inline, known_lfs):
        sha = hashlib.sha256(data).hexdigest()
        mine, bobs = (repos / who / "blobs" / sha[:2] / sha for who in ("alice/probe", "bob/secret"))
        assert mine.read_bytes() == bobs.read_bytes() == data
        assert not os.path.samefile(mine, bobs)
    assert not (srv.config.root / "blobs").exists()  # nothing is shared between repos


# ------------------------------------------------------------------ repo ids
def test_repo_ids_are_case_insensitive_like_the_hub(srv):
    """``alice/Pub`` exists: creating ``alice/pub`` is 409 naming ``alice/Pub`` (exist_ok
    gives its URL); ``alice/PUB`` reads, writes and deletes ``alice/Pub``; a dataset is a
    repo of another kind and may have the name."""
    api = HfApi(endpoint=srv.url, token=ALICE)
    api.create_repo("alice/Pub")
    with pytest.raises(HfHubHTTPError) as err:
        api.create_repo("alice/pub")
    assert err.value.response.status_code == 409 and "alice/Pub" in str(err.value)
    assert api.create_repo("alice/PUB", exist_ok=True).repo_id == "alice/Pub"
    api.upload_file(path_or_fileobj=b"hello", path_in_repo="a.txt", repo_id="ALICE/pUB")
    assert api.model_info("alice/pub").id == "alice/Pub"
    assert H.call(srv, "GET", "/alice/PUB/resolve/main/a.txt")[:2] == (200, b"hello")
    assert api.list_repo_files("Alice/pub") == ["a.txt"]
    api.create_repo("alice/pub", repo_type="dataset")
    assert sorted(p.name for p in (srv.config.root / "repos" / "models" / "alice").iterdir()) == ["Pub"]
    api.delete_repo("alice/PUB")
    assert H.call(srv, "GET", "/api/models/alice/Pub", token=ALICE)[0] == 404
    assert api.create_repo("alice/pub").repo_id == "alice/pub"
    assert H.call(srv, "GET", "/api/models/bob/PUB", token=BOB)[0] == 404


@pytest.mark.parametrize("tokens,orgs,says", [
    (["alice:secret-1a", "Alice:secret-2a"], [], "users 'Alice' and 'alice' differ only in case"),
    (["acme:secret-1a"], ["ACME:acme"], "organisation 'ACME' has the same name as a user"),
    (["bob:secret-1a"], ["Team:bob", "team:bob"],
     "organisations 'Team' and 'team' differ only in case"),
])
def test_names_that_differ_only_in_case_are_refused_at_start(tokens, orgs, says):
    """Repo ids ignore case, so user and organisation names must too: otherwise a user could
    hold the names of another's repos, and a 409 would name a private repo."""
    from msta.data.hub_server.auth import AuthConfig

    with pytest.raises(ValueError, match=says):
        AuthConfig.from_specs(tokens, orgs)
    ok = AuthConfig.from_specs(["alice:secret-1a", "alice:secret-2a"], ["team:alice"])
    assert ok.orgs_of("alice") == ["team"]

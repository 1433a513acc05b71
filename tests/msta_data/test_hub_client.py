"""The hub client (msta.data.hub_push / hub_pull / hub_versions / hub_cards) and the msta-hub CLI against the real server."""

from __future__ import annotations

import hashlib
import json
import logging
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from huggingface_hub import HfApi
from huggingface_hub.errors import HfHubHTTPError, RepositoryNotFoundError

from msta.data.hub_cards import CardInfo, card_metadata
from msta.data.hub_cli import main as cli_main
from msta.data.hub_ids import HubError, HubId, HubIntegrityError, hub_api, is_hub_id, parse_hub_id
from msta.data.hub_pull import materialize, pull, resolve
from msta.data.hub_push import push, push_dataset
from msta.data.hub_server import HubServer, ServerConfig
from msta.data.hub_versions import versions

SECRET = "alice-secret-0001"
REPO_ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def server(tmp_path, monkeypatch):
    srv = HubServer(ServerConfig(root=tmp_path / "hub", tokens=[f"alice:{SECRET}"])).start()
    monkeypatch.setenv("HF_ENDPOINT", srv.url)
    monkeypatch.setenv("HF_TOKEN", SECRET)
    yield srv
    srv.stop()


def _checkpoint(path: Path, seed: int, extra: dict[str, bytes] | None = None) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    (path / "config.json").write_text(json.dumps({"type": "msta", "seed": seed}))
    (path / "model.safetensors").write_bytes(hashlib.sha256(str(seed).encode()).digest() * 100)
    for rel, data in (extra or {}).items():
        (path / rel).write_bytes(data)
    return path


def _digests(root: Path) -> dict[str, str]:
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def test_parse_hub_id():
    assert parse_hub_id("alice/m@stage1-r0") == HubId("alice/m", "stage1-r0", "model")
    assert parse_hub_id("datasets/alice/d@v3.0") == HubId("alice/d", "v3.0", "dataset")
    assert parse_hub_id("alice/d", repo_type="dataset") == HubId("alice/d", None, "dataset")
    assert str(parse_hub_id("datasets/alice/d@v3.0")) == "datasets/alice/d@v3.0"
    for bad in ("alice", "a/b/c", "alice/m@", "alice/m@a b", "/abs/path"):
        with pytest.raises(ValueError, match="not a hub id"):
            parse_hub_id(bad)
    assert is_hub_id("alice/m@v1") and not is_hub_id(str(REPO_ROOT))


def test_push_two_versions_and_pull_each_by_tag_branch_and_sha(server, tmp_path):
    v1 = _checkpoint(tmp_path / "v1", 1, {"old.json": b"{}"})
    v2 = _checkpoint(tmp_path / "v2", 2)
    card = CardInfo(dataset_repo="alice/teacher", dataset_revision="v3.0", stage=1, round=0,
                        config={"lr": 0.001}, eval_table={"mask0": {"total": 0.97}, "mask50": {"total": 0.94}})
    s1 = push(v1, "alice/ckpt", tag="stage1-r0", card=card)
    s2 = push(v2, "alice/ckpt", tag="stage2-r0", card=CardInfo(stage=2, metrics={"total": 0.99}))
    hub_api().create_branch("alice/ckpt", branch="field", revision=s1)
    expected1 = _digests(v1)
    expected2 = _digests(v2)
    for spec, want in (("alice/ckpt@stage1-r0", expected1), ("alice/ckpt@stage2-r0", expected2),
                       ("alice/ckpt@field", expected1), ("alice/ckpt@main", expected2), ("alice/ckpt", expected2),
                       (f"alice/ckpt@{s1}", expected1), (f"alice/ckpt@{s2[:8]}", expected2)):
        got = _digests(pull(spec, tmp_path / "pulled" / spec.replace("/", "_")))
        readme = got.pop("README.md")
        assert got == want, spec  # old.json of v1 is gone in v2: each commit is a whole checkpoint
        assert readme
    assert not [p for p in (tmp_path / "pulled").iterdir() if p.name.startswith(".")]  # no partial dirs

    pulled = tmp_path / "pulled" / "alice_ckpt@stage1-r0"
    meta = card_metadata((pulled / "README.md").read_text())
    assert meta["msta"]["dataset"] == {"repo": "alice/teacher", "revision": "v3.0"}
    assert meta["msta"]["stage"] == 1 and meta["msta"]["round"] == 0 and meta["msta"]["config"] == {"lr": 0.001}

    listed = versions("alice/ckpt")
    assert listed.tags == {"stage1-r0": s1, "stage2-r0": s2}
    assert listed.branches == {"main": s2, "field": s1}
    by_sha = {v.sha: v for v in listed.commits}
    assert [v.sha for v in listed.commits][:2] == [s2, s1]
    assert by_sha[s1].metrics == {"mask0/total": 0.97, "mask50/total": 0.94} and by_sha[s1].tags == ["stage1-r0"]
    assert by_sha[s2].metrics == {"total": 0.99} and by_sha[s2].branches == ["main"]
    assert "stage2-r0" in listed.to_text()


def test_push_same_content_again_and_tag_rules(server, tmp_path):
    ckpt = _checkpoint(tmp_path / "c", 3)
    s1 = push(ckpt, "alice/same", tag="a")
    assert push(ckpt, "alice/same", tag="a") == s1  # nothing changed: no new commit, tag unchanged
    (ckpt / "config.json").write_text("{}")
    s2 = push(ckpt, "alice/same")
    with pytest.raises(HubError, match="already points to"):
        push(ckpt, "alice/same", tag="a")
    assert push(ckpt, "alice/same", tag="a", move_tag=True) == s2
    assert resolve("alice/same@a").revision == s2
    (ckpt / "optimizer.pt").write_bytes(b"\x80\x04pickle")
    with pytest.raises(HubError, match="pickle"):
        push(ckpt, "alice/same")


def test_corrupted_blob_fails_pull_and_leaves_nothing(server, tmp_path):
    ckpt = _checkpoint(tmp_path / "c", 4)
    push(ckpt, "alice/corrupt", tag="t")
    weights = hashlib.sha256((ckpt / "model.safetensors").read_bytes()).hexdigest()
    blob = server.config.root / "repos" / "models" / "alice" / "corrupt" / "blobs" / weights[:2] / weights
    data = bytearray(blob.read_bytes())
    data[100] ^= 0xFF
    blob.write_bytes(bytes(data))  # same size, different bytes
    dest = tmp_path / "out" / "ckpt"
    with pytest.raises(HubIntegrityError, match=r"model\.safetensors.*was not written"):
        pull("alice/corrupt@t", dest)
    assert not dest.exists() and list((tmp_path / "out").iterdir()) == []
    blob.write_bytes(bytes(data[:1000]))  # truncated: the transfer itself breaks
    with pytest.raises(HubError, match="was not written"):
        pull("alice/corrupt@t", dest)
    assert not dest.exists() and list((tmp_path / "out").iterdir()) == []


def test_pull_refuses_to_clobber_and_reports_missing_repo(server, tmp_path):
    push(_checkpoint(tmp_path / "c", 5), "alice/x")
    dest = tmp_path / "existing"
    dest.mkdir()
    (dest / "keep.txt").write_text("mine")
    with pytest.raises(FileExistsError):
        pull("alice/x", dest)
    assert pull("alice/x", dest, overwrite=True) == dest and not (dest / "keep.txt").exists()
    with pytest.raises(RepositoryNotFoundError):
        pull("alice/does-not-exist", tmp_path / "none")
    assert not (tmp_path / "none").exists()


def test_private_push_refused_to_anonymous_pull(server, tmp_path):
    push(_checkpoint(tmp_path / "c", 6), "alice/priv", private=True)
    with pytest.raises(RepositoryNotFoundError):
        pull("alice/priv", tmp_path / "anon", token=False)
    with pytest.raises(HfHubHTTPError) as wrong:
        pull("alice/priv", tmp_path / "wrong", token="wrong-token-0000")
    assert wrong.value.response.status_code == 401
    assert not (tmp_path / "anon").exists() and not (tmp_path / "wrong").exists()
    assert (pull("alice/priv", tmp_path / "ok") / "config.json").exists()


def test_large_file_inline_upload(server, tmp_path):
    big = os.urandom(11 * 1024 * 1024)
    ckpt = _checkpoint(tmp_path / "c", 7, {"big.safetensors": big})
    push(ckpt, "alice/big")
    pulled = pull("alice/big", tmp_path / "pulled")
    assert hashlib.sha256((pulled / "big.safetensors").read_bytes()).digest() == hashlib.sha256(big).digest()


def test_large_file_through_lfs(tmp_path):
    """With --lfs-threshold the client takes the Git LFS path (batch, PUT, verify)."""
    cfg = ServerConfig(root=tmp_path / "hub", tokens=[f"alice:{SECRET}"], lfs_threshold=10 * 1024 * 1024)
    big = os.urandom(11 * 1024 * 1024)
    ckpt = _checkpoint(tmp_path / "c", 8, {"big.safetensors": big})
    with HubServer(cfg) as srv:
        env = {**os.environ, "HF_ENDPOINT": srv.url, "HF_TOKEN": SECRET, "HF_HUB_DISABLE_XET": "1",
               "HF_HOME": str(tmp_path / "hf")}
        code = f"from msta.data.hub_push import push; print(push({str(ckpt)!r}, 'alice/lfs', tag='v1'))"
        out = subprocess.run([sys.executable, "-c", code], check=False, env=env, capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stderr
        files = {f.path: f for f in HfApi(endpoint=srv.url, token=SECRET).list_repo_tree("alice/lfs")}
        assert files["big.safetensors"].lfs.sha256 == hashlib.sha256(big).hexdigest()
        assert files["config.json"].lfs is None
        pulled = pull("alice/lfs@v1", tmp_path / "pulled", endpoint=srv.url, token=SECRET)
        assert (pulled / "big.safetensors").read_bytes() == big


def test_push_dataset_tags_codebase_version(server, tmp_path, write_dataset):
    root = tmp_path / "ds"
    write_dataset(root, [3])
    card = CardInfo(config={"episodes": 1})
    s1 = push_dataset(root, "alice/teacher", card=card)
    s2 = push_dataset(root, "alice/teacher", card=card, tag="round1")  # same content: same commit
    assert s1 == s2
    write_dataset(root, [4], seed0=1, append=True)  # a second version
    s3 = push_dataset(root, "alice/teacher", card=card)
    refs = hub_api().list_repo_refs("alice/teacher", repo_type="dataset")
    assert {t.name: t.target_commit for t in refs.tags} == {"v3.0": s3, "round1": s1}
    pulled = pull("datasets/alice/teacher@v3.0", tmp_path / "pulled")
    assert (pulled / "meta" / "info.json").read_bytes() == (root / "meta" / "info.json").read_bytes()
    assert json.loads((pulled / "meta" / "info.json").read_text())["total_episodes"] == 2
    card = card_metadata((pulled / "README.md").read_text())
    assert card["msta"]["lerobot"]["robot_type"] == "a1" and "LeRobot" in card["tags"]
    with pytest.raises(FileNotFoundError, match="info.json"):
        push_dataset(tmp_path / "v1", "alice/nope")


def test_tokens_never_logged_or_printed(server, tmp_path, caplog, capfd):
    with caplog.at_level(logging.DEBUG):
        sha = push(_checkpoint(tmp_path / "c", 9), "alice/quiet", tag="t", private=True)
        pull("alice/quiet@t", tmp_path / "p")
        with pytest.raises(HfHubHTTPError):
            pull("alice/quiet@t", tmp_path / "q", token="another-secret-42")
        assert cli_main(["versions", "alice/quiet", "--json"]) == 0
    out, err = capfd.readouterr()
    text = caplog.text + out + err
    assert sha[:12] in text  # the logs were captured...
    assert SECRET not in text and "another-secret-42" not in text  # ...and hold no token


def test_cli_push_pull_versions(server, tmp_path, capsys):
    ckpt = _checkpoint(tmp_path / "c", 10)
    (tmp_path / "eval.json").write_text(json.dumps({"total_reward": 0.95}))
    assert cli_main(["push", str(ckpt), "alice/cli", "--tag", "stage1-r0", "--stage", "1", "--round", "0",
                     "--eval-json", str(tmp_path / "eval.json")]) == 0
    sha = capsys.readouterr().out.strip()
    assert cli_main(["pull", "alice/cli@stage1-r0", str(tmp_path / "pulled")]) == 0
    assert _digests(tmp_path / "pulled").keys() == {"README.md", "config.json", "model.safetensors"}
    capsys.readouterr()
    assert cli_main(["versions", "alice/cli", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["tags"] == {"stage1-r0": sha}
    assert data["commits"][0]["metrics"] == {"total_reward": 0.95}
    assert data["commits"][0]["card"]["msta"]["config"]["seed"] == 10  # config.json recorded in the card
    capsys.readouterr()
    assert cli_main(["pull", "alice/cli@no-such-tag", str(tmp_path / "x")]) == 1
    assert "error" in capsys.readouterr().err and not (tmp_path / "x").exists()
    with pytest.raises(SystemExit):
        cli_main(["--help"])


def test_cli_serve_subprocess_restart(tmp_path):
    """`msta-hub serve` as a real process: data pushed before a restart is there after it."""
    port_file, root = tmp_path / "port", tmp_path / "hub"
    tokens = tmp_path / "tokens"
    tokens.write_text(f"# users\nalice:{SECRET}\n")

    def start() -> tuple[subprocess.Popen, str]:
        port_file.unlink(missing_ok=True)
        proc = subprocess.Popen([sys.executable, "-m", "msta.data.hub_cli", "serve", "--root", str(root),
                                 "--token-file", str(tokens), "--port-file", str(port_file)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 30
        while not (port_file.exists() and port_file.read_text().strip()):
            assert proc.poll() is None and time.monotonic() < deadline, "server did not start"
            time.sleep(0.05)
        return proc, f"http://127.0.0.1:{port_file.read_text().strip()}"

    proc, url = start()
    try:
        sha = push(_checkpoint(tmp_path / "c", 11), "alice/served", tag="t", endpoint=url, token=SECRET)
    finally:
        proc.terminate()
        _, err1 = proc.communicate(timeout=10)
    proc, url = start()
    try:
        assert resolve("alice/served@t", endpoint=url, token=SECRET).revision == sha
        assert (pull("alice/served@t", tmp_path / "p", endpoint=url, token=False) / "config.json").exists()
    finally:
        proc.terminate()
        _, err2 = proc.communicate(timeout=10)
    assert "POST /api/models/alice/served/commit/main -> 200" in err1
    assert SECRET not in err1 + err2


def test_materialize_caches_by_commit(server, tmp_path):
    sha = push(_checkpoint(tmp_path / "c", 12), "alice/mat", tag="t")
    local = tmp_path / "c"
    assert materialize(local) == local
    got = materialize("alice/mat@t", cache_dir=tmp_path / "cache")
    assert got == tmp_path / "cache" / "models" / "alice" / "mat" / sha
    assert materialize(f"alice/mat@{sha[:9]}", cache_dir=tmp_path / "cache") == got


def test_a_dataset_card_follows_the_data_after_an_append(server, tmp_path, write_dataset):
    """Pulled, appended to and pushed again: msta's card is rebuilt from the new info.json
    (it kept saying the old episode count); a README.md of the user's own is kept as is."""
    root = tmp_path / "ds"
    write_dataset(root, [3])
    push_dataset(root, "alice/grow", card=CardInfo(config={"episodes": 1}))
    copy = pull("datasets/alice/grow", tmp_path / "copy")
    assert card_metadata((copy / "README.md").read_text())["msta"]["lerobot"][
        "total_episodes"] == 1
    write_dataset(copy, [4, 2], seed0=5, append=True)
    push_dataset(copy, "alice/grow")
    again = pull("datasets/alice/grow", tmp_path / "again")
    meta = card_metadata((again / "README.md").read_text())
    assert meta["msta"]["lerobot"]["total_episodes"] == 3
    assert meta["msta"]["lerobot"]["total_frames"] == 3 + 4 + 2
    assert meta["msta"]["config"] == {"episodes": 1}  # what the card recorded stays

    (copy / "README.md").write_text("# my own notes\n")
    push_dataset(copy, "alice/grow")
    mine = pull("datasets/alice/grow", tmp_path / "mine")
    assert (mine / "README.md").read_text() == "# my own notes\n"

"""What stays on this machine: lock files, MuJoCo's log, quarantined files and caches are
never pushed (msta's push, and a plain ``upload_folder`` given ``PUSH_IGNORE_PATTERNS``),
and pulled commits are cached where Hugging Face's environment variables say. Against the
real hub server on 127.0.0.1."""

from __future__ import annotations

from pathlib import Path

import pytest
from msta_test_helpers import hub_as

from msta.data import layout as L
from msta.data.hub_ids import hub_api
from msta.data.hub_pull import default_cache_dir, materialize
from msta.data.hub_push import PUSH_IGNORE_PATTERNS, push, push_dataset
from msta.data.locate import locate

#: machine-local files planted in a directory before it is pushed
LOCAL = (L.LOCK_NAME, f"sub/{L.LOCK_NAME}", "MUJOCO_LOG.TXT", "sub/MUJOCO_LOG.TXT",
         f"{L.QUARANTINE_DIR}/2026-01-01T00:00:00/data/x.parquet",
         ".cache/huggingface/download/config.json.metadata")


@pytest.fixture
def hub(tmp_path, monkeypatch):
    with hub_as(tmp_path / "hub", monkeypatch) as srv:
        yield srv


def _plant(root: Path) -> None:
    for rel in LOCAL:
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text("local")


def _files(repo: str, repo_type: str = "model") -> set[str]:
    return set(hub_api().list_repo_files(repo, repo_type=repo_type))


def test_locks_logs_quarantine_and_caches_never_leave_the_machine(hub, tmp_path,
                                                                   write_dataset):
    root = tmp_path / "ds"
    write_dataset(root, [4, 4])
    assert (root / L.LOCK_NAME).is_file()  # the writer's lock stays behind
    _plant(root)
    push_dataset(root, "alice/ds")
    pushed = _files("alice/ds", "dataset")
    assert L.INFO_PATH in pushed and L.MANIFEST_PATH in pushed
    assert not pushed & set(LOCAL) and not any(".cache" in p for p in pushed)

    ckpt = tmp_path / "ckpt"
    ckpt.mkdir()
    (ckpt / "config.json").write_text('{"type": "gru"}')
    _plant(ckpt)
    push(ckpt, "alice/m")
    assert _files("alice/m") == {"config.json"}

    # a plain huggingface_hub upload with msta's patterns leaves out the same files ...
    api = hub_api()
    api.create_repo("alice/plain", repo_type="dataset")
    api.upload_folder(folder_path=root, repo_id="alice/plain", repo_type="dataset",
                      ignore_patterns=PUSH_IGNORE_PATTERNS)
    assert _files("alice/plain", "dataset") == pushed
    # ... which it publishes without them (huggingface_hub skips only .git and .cache/huggingface)
    lone = tmp_path / "lone"
    lone.mkdir()
    (lone / "config.json").write_text("{}")
    (lone / L.LOCK_NAME).write_text("123")
    api.create_repo("alice/unfiltered")
    api.upload_folder(folder_path=lone, repo_id="alice/unfiltered")
    assert L.LOCK_NAME in _files("alice/unfiltered")


def test_pulled_commits_are_cached_where_hf_home_says(hub, tmp_path, monkeypatch):
    ckpt = tmp_path / "ckpt"
    ckpt.mkdir()
    (ckpt / "config.json").write_text('{"type": "gru"}')
    sha = push(ckpt, "alice/c", tag="v1")
    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv("HOME", str(home))
    for name in ("MSTA_HUB_CACHE", "HF_HOME", "XDG_CACHE_HOME"):
        monkeypatch.delenv(name, raising=False)
    assert default_cache_dir() == home / ".cache" / "huggingface" / "msta" / "hub"

    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf"))
    got = locate("alice/c@v1", "model", "--policy.path")  # what every command does
    assert got == tmp_path / "hf" / "msta" / "hub" / "models" / "alice" / "c" / sha
    assert (got / "config.json").read_text() == '{"type": "gru"}'
    assert not any(home.rglob("*"))  # nothing in the home directory

    monkeypatch.delenv("HF_HOME")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert materialize("alice/c@v1").is_relative_to(tmp_path / "xdg" / "huggingface" / "msta")
    monkeypatch.setenv("MSTA_HUB_CACHE", str(tmp_path / "own"))  # msta's own variable wins
    assert materialize("alice/c@v1") == tmp_path / "own" / "models" / "alice" / "c" / sha
    assert not any(home.rglob("*"))


#: LeRobot pushes an msta dataset with the allow-list docs/hub.md gives (LeRobot's hub
#: client reads HF_ENDPOINT at import: a fresh process). Its card step afterwards asks
#: huggingface.co to validate the card (huggingface_hub's RepoCard.validate names that host),
#: which fails without Internet access: only the upload is checked here.
LEROBOT_PUSH = """
import sys
from lerobot.datasets.lerobot_dataset import LeRobotDataset
ds = LeRobotDataset("alice/viaLerobot", root=sys.argv[1])
try:
    ds.push_to_hub(allow_patterns=["data/", "meta/", "videos/"])
except Exception as e:
    print("card step:", type(e).__name__)
"""


@pytest.mark.slow
def test_lerobot_and_hf_cli_pushes_leave_local_files_out_as_documented(hub, tmp_path,
                                                                         write_dataset):
    import os
    import re
    import subprocess
    import sys

    root = tmp_path / "ds"
    write_dataset(root, [4, 4])
    _plant(root)
    env = {**os.environ, "HF_HOME": str(tmp_path / "hf"), "HF_HUB_DISABLE_XET": "1"}
    run = subprocess.run([sys.executable, "-c", LEROBOT_PUSH, str(root)], env=env,
                         capture_output=True, text=True, timeout=300, check=False)
    assert run.returncode == 0, run.stderr[-3000:]
    pushed = _files("alice/viaLerobot", "dataset")
    assert L.INFO_PATH in pushed and L.MANIFEST_PATH in pushed
    assert not any(L.LOCK_NAME in p or "MUJOCO" in p or L.QUARANTINE_DIR in p for p in pushed)

    # huggingface_hub's `hf upload` with the --exclude patterns docs/hub.md gives
    doc = (Path(__file__).resolve().parents[2] / "docs" / "hub.md").read_text()
    line = re.search(r"^hf upload alice/a1-teacher data/a1-teacher .*?[^\\]$", doc,
                     re.MULTILINE | re.DOTALL).group(0)
    argv = [a.strip('"') for a in line.replace("\\\n", " ").split()]
    argv[2], argv[3] = "alice/viaCli", str(root)
    cli = Path(sys.executable).with_name("hf")
    run = subprocess.run([str(cli), *argv[1:]], env=env, capture_output=True, text=True,
                         timeout=300, check=False)
    assert run.returncode == 0, run.stderr[-3000:]
    assert _files("alice/viaCli", "dataset") == _files_of(root)


def _files_of(root: Path) -> set[str]:
    """What msta's push would publish of ``root`` (its own filter)."""
    from msta.data.hub_push import _local_files

    return set(_local_files(root))

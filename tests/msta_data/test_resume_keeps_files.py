"""Issue 41 (8, 9): ``msta-collect --resume`` never deletes a committed episode or a file it
does not know, whatever the state of meta/: what the last commit does not list is moved to
``.msta-quarantine/<time>/`` (relative paths kept) and reported; only the writer's own
partial ``.tmp`` writes are deleted. The quarantine is never read or pushed.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from msta_test_helpers import running_hub  # registered by tests/conftest.py

from msta.data.layout import QUARANTINE_DIR
from msta.data.windows import WindowDataset, load_episode_table

REPO = Path(__file__).resolve().parents[2]
SECRET = "alice-secret-0041"
# msta-collect on the smallest simulator: the zero teacher, flat ground, 10-step episodes.
SMALL = ["--teacher.type=zero", "--num_envs=2", "--episode_length_s=0.2", "--progress=false",
         "--env.nthread=1", "--env.terrain.types=[flat]", "--env.terrain.num_levels=1",
         "--env.terrain.max_init_level=0", "--env.terrain.border=2.0"]
NEWER = ("data/chunk-000/file-001.parquet", "meta/episodes/chunk-000/file-001.parquet")


def _quarantined(root: Path) -> dict[str, bytes]:
    """Relative path (inside its time folder) -> bytes of every quarantined file."""
    out = {}
    for folder in sorted((root / QUARANTINE_DIR).iterdir()):
        for p in sorted(folder.rglob("*")):
            if p.is_file():
                out[p.relative_to(folder).as_posix()] = p.read_bytes()
    return out


def _resume(root: Path, episodes: int) -> subprocess.CompletedProcess:
    """``msta-collect --resume`` as a subprocess (what a user runs); the zero teacher extends
    the synthetic datasets' gait episodes, a mix asked for."""
    return subprocess.run([sys.executable, "-m", "msta.collect.record", f"--root={root}",
                           "--resume=true", f"--episodes={episodes}", *SMALL,
                           "--allow_mixed_settings=true"], cwd=REPO,
                          capture_output=True, text=True, timeout=300, check=False)


def test_resume_after_an_older_meta_pair_keeps_the_newer_episodes(tmp_path, write_dataset):
    """The audit's case: meta/info.json and its manifest restored from a backup taken at 4
    episodes, then ``msta-collect --resume`` (a real subprocess): the 4 newer committed
    episodes used to be deleted and recorded again."""
    root = tmp_path / "ds"
    write_dataset(root, [5] * 4)
    backup = {n: (root / "meta" / n).read_bytes() for n in ("info.json", "msta_checksums.json")}
    write_dataset(root, [5] * 4, append=True)  # same terrains, so the same tasks file
    newer = {rel: (root / rel).read_bytes() for rel in NEWER}
    for name, content in backup.items():
        (root / "meta" / name).write_bytes(content)
    proc = _resume(root, 6)
    assert proc.returncode == 0, proc.stderr
    assert _quarantined(root) == newer  # every byte of the newer episodes kept
    line = next(x for x in proc.stderr.splitlines() if QUARANTINE_DIR in x)
    assert "moved 2 file(s)" in line and "nothing was deleted" in line and NEWER[0] in line
    assert len(load_episode_table(root)) == 6  # recorded on top of the restored meta/
    assert len(WindowDataset(root, ["joint_pos"], T=2)) == 20 + 2 * 10


@pytest.fixture(scope="module")
def hub_server(tmp_path_factory):
    with running_hub(tmp_path_factory.mktemp("hub"), f"alice:{SECRET}") as srv:
        yield srv


def test_resume_moves_unknown_files_aside_and_pushes_none_of_them(
        tmp_path, write_dataset, hub_server, monkeypatch):
    """A user's files in the chunk directories used to be deleted silently by --resume."""
    from msta.data.hub_cli import main as hub_main
    from msta.data.hub_ids import hub_api

    root = tmp_path / "ds"
    write_dataset(root, [5] * 3)
    mine = {"data/chunk-000/file-000.parquet.backup": (root / "data/chunk-000/file-000.parquet")
            .read_bytes(), "data/chunk-000/notes.txt": b"checked by hand\n",
            "meta/episodes/chunk-000/notes.md": b"# notes\n", "meta/mine.tmp": b"keep me"}
    partial = ("data/chunk-000/file-001.parquet.tmp", "meta/info.json.tmp")  # a killed write
    for rel, content in mine.items():
        (root / rel).write_bytes(content)
    for rel in partial:
        (root / rel).write_bytes(b"partial")
    proc = _resume(root, 3)  # opens the dataset, nothing to add
    assert proc.returncode == 0, proc.stderr
    assert _quarantined(root) == mine
    assert not any((root / rel).exists() for rel in (*mine, *partial))
    assert f"{QUARANTINE_DIR}/" in proc.stderr and "nothing was deleted" in proc.stderr
    assert len(WindowDataset(root, ["joint_pos"], T=2)) == 15  # never read from there
    monkeypatch.setenv("HF_ENDPOINT", hub_server.url)
    monkeypatch.setenv("HF_TOKEN", SECRET)
    assert hub_main(["push-dataset", str(root), "alice/resumed"]) == 0
    pushed = hub_api().list_repo_files("alice/resumed", repo_type="dataset")
    assert "data/chunk-000/file-000.parquet" in pushed
    assert not [f for f in pushed if QUARANTINE_DIR in f or "notes" in f]


def test_a_second_resume_gets_its_own_quarantine_folder(tmp_path, write_dataset):
    """Two resumes within one second do not mix (or overwrite) what they set aside."""
    from msta.data.writer import DatasetWriter

    root = tmp_path / "ds"
    write_dataset(root, [5])
    for n in range(2):
        (root / "data/chunk-000/notes.txt").write_text(f"note {n}")
        DatasetWriter.open(root).close()
    folders = sorted((root / QUARANTINE_DIR).iterdir())
    assert [(f / "data/chunk-000/notes.txt").read_text() for f in folders] == ["note 0",
                                                                             "note 1"]

"""Issue 15 (9, 11): msta-collect checks its configuration, teacher and simulator before it
creates anything, says what is wrong in one line, and a failed first run never blocks the
rerun."""

from __future__ import annotations

import pytest

from msta.collect.record import main
from msta.data.integrity import Generation, Manifest, digest_file
from msta.data.windows import load_episode_table
from msta.data.writer import DatasetWriter

SMALL = ["--teacher.type=zero", "--num_envs=2", "--episode_length_s=0.2", "--progress=false",
         "--env.nthread=1", "--env.terrain.types=[flat]", "--env.terrain.num_levels=1",
         "--env.terrain.border=2.0", "--env.randomization.pool_size=2"]


def _fails(args: list[str]) -> str:
    with pytest.raises(SystemExit) as err:
        main(args)
    message = str(err.value)
    assert message.startswith("msta-collect: error: ") and "\n" not in message
    assert "Couldn't instantiate" not in message
    return message


@pytest.mark.parametrize("flag, says", [
    ("--env.terrain.max_init_level=11", "max_init_level=11: the terrain has levels 0..9"),
    ("--env.terrain.num_levels=0", "TerrainConfig: num_levels=0 must be >= 1"),
    ("--episodes=abc", "`episodes`: Couldn't parse 'abc'"),
    ("--teacher.type=imported", "teacher type 'imported' needs --teacher.path"),
])
def test_config_errors_are_one_line_and_create_nothing(tmp_path, flag, says):
    root = tmp_path / "ds"
    assert says in _fails([f"--root={root}", flag])
    assert not root.exists()


def test_a_failed_first_run_leaves_nothing_and_the_rerun_works(tmp_path):
    root = tmp_path / "ds"
    spec = tmp_path / "teacher.txt"
    spec.write_text("not a teacher spec")
    assert "teacher.txt" in _fails([f"--root={root}", "--episodes=2", *SMALL,
                                    "--teacher.type=imported", f"--teacher.path={spec}"])
    assert not root.exists()  # the teacher is built before the dataset is created
    main([f"--root={root}", "--episodes=2", *SMALL])
    assert len(load_episode_table(root)) == 2


def test_an_empty_dataset_left_by_a_run_that_recorded_nothing_is_reused(tmp_path):
    root = tmp_path / "ds"
    DatasetWriter.create(root, "local/a1_teacher").close()  # a run killed before its 1st flush
    main([f"--root={root}", "--episodes=2", *SMALL])
    assert len(load_episode_table(root)) == 2
    assert "--resume=true" in _fails([f"--root={root}", "--episodes=3", *SMALL])



@pytest.mark.parametrize("root", ["/dev/null", "FILE"])
def test_a_root_that_is_not_a_folder_is_one_line(tmp_path, root):
    path = tmp_path / "file.txt"
    path.write_text("mine")
    root = root.replace("FILE", str(path))
    assert f"--root={root} is not a folder" in _fails([*SMALL, f"--root={root}", "--episodes=2"])
    assert path.read_text() == "mine"


def test_resume_refuses_other_recording_settings_naming_each(tmp_path, capsys):
    """A resumed recording with another teacher, episode length and terrains: one line
    naming each difference, nothing appended; with --allow_mixed_settings the episodes are
    appended and meta/msta.json keeps each session's settings from its first episode."""
    import json

    root = tmp_path / "ds"
    main([*SMALL, f"--root={root}", "--episodes=2"])
    before = sorted(p.name for p in (root / "data").rglob("*.parquet"))
    other = [*SMALL, "--teacher.type=gait", "--episode_length_s=0.4",
             "--env.terrain.types=[flat, stairs_up]"]
    message = _fails([*other, f"--root={root}", "--episodes=4", "--resume=true"])
    for diff in ('teacher "zero" -> "gait"', "episode_length_s 0.2 -> 0.4",
                 'terrains ["flat"] -> ["flat", "stairs_up"]', "teacher_revision"):
        assert diff in message, message
    assert "--allow_mixed_settings=true" in message
    assert sorted(p.name for p in (root / "data").rglob("*.parquet")) == before
    main([*SMALL, f"--root={root}", "--episodes=3", "--resume=true"])  # the same settings
    main([*other, f"--root={root}", "--episodes=5", "--resume=true",
          "--allow_mixed_settings=true"])
    blocks = json.loads((root / "meta/msta.json").read_text())["recordings"]
    assert [(b["from_episode"], b["teacher"], b["episode_length_s"]) for b in blocks] == [
        (0, "zero", 0.2), (3, "gait", 0.4)]
    table = load_episode_table(root)
    assert table["provenance/policy"].tolist() == ["zero"] * 3 + ["gait"] * 2
    # the next resume compares with the latest session's settings
    main([*other, f"--root={root}", "--episodes=6", "--resume=true"])
    assert "teacher \"gait\" -> \"zero\"" in _fails([*SMALL, f"--root={root}", "--episodes=7",
                                                    "--resume=true"])


def test_a_dataset_without_recorded_settings_is_compared_on_its_teacher(tmp_path):
    import json

    root = tmp_path / "ds"
    main([*SMALL, f"--root={root}", "--episodes=2"])
    meta = json.loads((root / "meta/msta.json").read_text())
    del meta["recordings"]  # as recorded before the settings were kept
    (root / "meta/msta.json").write_text(json.dumps(meta, indent=4))
    manifest = Manifest.load(root)  # the manifest follows the edit
    files = dict(manifest.committed.files)
    files["meta/msta.json"] = digest_file(root / "meta/msta.json", use_cache=False)
    gen = Generation(manifest.committed.total_episodes, manifest.committed.total_frames, files)
    (root / "meta/msta_checksums.json").write_bytes(Manifest(gen).dumps())
    assert 'teacher "zero" -> "gait"' in _fails([*SMALL, "--teacher.type=gait",
                                                 f"--root={root}", "--episodes=3",
                                                 "--resume=true"])
    main([*SMALL, "--episode_length_s=0.4", f"--root={root}", "--episodes=3", "--resume=true"])
    assert len(load_episode_table(root)) == 3

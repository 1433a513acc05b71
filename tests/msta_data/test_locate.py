"""Issue 15 (11): a mistyped relative dataset path is reported as a missing local path, never
looked up on a hub (and no hub at all is asked unless HF_ENDPOINT is set)."""

from __future__ import annotations

import pytest

from msta.data.locate import (
    locate,
    locate_checkpoint,
    locate_dataset,
    looks_like_path,
    reads_as_hub_id,
)


def test_paths_and_hub_ids_are_told_apart(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "outputs").mkdir()
    assert looks_like_path("./x") and looks_like_path("/abs/x") and looks_like_path("a/b/c")
    assert looks_like_path("outputs/a1_techer")  # its first component exists here
    assert not looks_like_path("alice/a1") and not looks_like_path("datasets/alice/a1@v3.0")
    assert reads_as_hub_id("alice/a1@v1") and reads_as_hub_id("datasets/alice/a1")
    assert not reads_as_hub_id("outputs/a1_techer") and not reads_as_hub_id("./alice/a1")
    (tmp_path / "alice" / "a1").mkdir(parents=True)
    assert not reads_as_hub_id("alice/a1")  # an existing path is local (rule 1)


def test_a_typo_in_a_relative_dataset_path_is_not_looked_up_on_a_hub(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("HF_ENDPOINT", raising=False)
    (tmp_path / "outputs").mkdir()
    for spec in ("outputs/a1_techer", "outpts/a1_teacher", "datasets/outpts/a1_teacher@v1"):
        with pytest.raises(FileNotFoundError, match="no such dataset directory") as err:
            locate_dataset(spec)
        assert str(tmp_path / spec.split("@")[0]) in str(err.value)
    with pytest.raises(FileNotFoundError, match="set HF_ENDPOINT"):
        locate_dataset("outpts/a1_teacher")


def test_a_hub_failure_names_both_readings(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("HF_ENDPOINT", "http://127.0.0.1:9")  # nothing listens there
    monkeypatch.setenv("MSTA_HUB_CACHE", str(tmp_path / "cache"))
    with pytest.raises(FileNotFoundError) as err:
        locate("alice/a1_teacher", "dataset", "--dataset")
    message = str(err.value)
    assert "no such dataset directory" in message and "the hub at http://127.0.0.1:9" in message
    assert "\n" not in message


def test_datasets_and_checkpoints_are_checked_after_locating(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("HF_ENDPOINT", raising=False)
    (tmp_path / "empty").mkdir()
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="--dataset is required"):
        locate_dataset("")
    with pytest.raises(FileNotFoundError, match=r"meta/info\.json missing"):
        locate_dataset("empty")
    assert locate_checkpoint("empty").resolve() == tmp_path / "empty"
    with pytest.raises(FileNotFoundError, match="not a checkpoint directory"):
        locate_checkpoint("file", "--policy")
    # a revision is added to a hub id that names none; the message shows what was asked
    with pytest.raises(FileNotFoundError, match=r"'alice/m@stage1-r0'.*set HF_ENDPOINT"):
        locate_checkpoint("alice/m", "--policy.path", revision="stage1-r0")

"""Issue 15 (11): a mistyped relative dataset path is reported as a missing local path, never
looked up on a hub (and no hub at all is asked unless HF_ENDPOINT is set)."""

from __future__ import annotations

import pytest

from msta_data.locate import locate, looks_like_path
from train.offline import resolve_dataset


def test_paths_and_hub_ids_are_told_apart(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "outputs").mkdir()
    assert looks_like_path("./x") and looks_like_path("/abs/x") and looks_like_path("a/b/c")
    assert looks_like_path("outputs/a1_techer")  # its first component exists here
    assert not looks_like_path("alice/a1") and not looks_like_path("datasets/alice/a1@v3.0")


def test_a_typo_in_a_relative_dataset_path_is_not_looked_up_on_a_hub(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("HF_ENDPOINT", raising=False)
    (tmp_path / "outputs").mkdir()
    for spec in ("outputs/a1_techer", "outpts/a1_teacher", "datasets/outpts/a1_teacher@v1"):
        with pytest.raises(FileNotFoundError, match="no such dataset directory") as err:
            resolve_dataset(spec)
        assert str(tmp_path / spec.split("@")[0]) in str(err.value)
    with pytest.raises(FileNotFoundError, match="set HF_ENDPOINT"):
        resolve_dataset("outpts/a1_teacher")


def test_a_hub_failure_names_both_readings(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("HF_ENDPOINT", "http://127.0.0.1:9")  # nothing listens there
    monkeypatch.setenv("MSTA_HUB_CACHE", str(tmp_path / "cache"))
    with pytest.raises(FileNotFoundError) as err:
        locate("alice/a1_teacher", "dataset", "--dataset")
    message = str(err.value)
    assert "no such dataset directory" in message and "the hub at http://127.0.0.1:9" in message
    assert "\n" not in message

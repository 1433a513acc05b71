"""Issue 15 (10): a checkpoint from a stranger is checked before anything is allocated, and
every failure is one line naming the file (load_policy, the path msta-eval and
msta-correct take, and msta-train --resume)."""

from __future__ import annotations

import json
import pickle
import shutil
from pathlib import Path

import pytest

from msta.data.stats import load_stats
from msta.policies.checkpoint import CheckpointError
from msta.policies.factory import load_policy, make_policy
from msta.policies.msta import MSTAConfig


@pytest.fixture(scope="module")
def good(synthetic_dataset, tmp_path_factory) -> Path:
    cfg = MSTAConfig.from_preset("tiny", input_sensors=("command", "joint_pos", "gravity"))
    path = tmp_path_factory.mktemp("ckpt") / "good"
    make_policy(cfg, load_stats(synthetic_dataset)).save_pretrained(path)
    return path


@pytest.fixture
def ckpt(good, tmp_path) -> Path:
    path = tmp_path / "stranger"
    shutil.copytree(good, path)
    return path


def _edit_config(path: Path, **kv) -> None:
    cfg = json.loads((path / "config.json").read_text())
    cfg.update(kv)
    (path / "config.json").write_text(json.dumps(cfg))


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


DAMAGES = {
    "huge dim": (lambda p: _edit_config(p, dim=1048576, num_heads=1),
                 r"config\.json: describes a [\d,]+-parameter msta model, more than the limit"),
    "garbage config": (lambda p: (p / "config.json").write_bytes(b"\x00{not json"),
                       r"config\.json: not valid JSON"),
    "config list": (lambda p: (p / "config.json").write_text("[1, 2]"),
                    r"config\.json: expected a JSON object"),
    "unknown type": (lambda p: _edit_config(p, type="nope"),
                     r"config\.json: unknown policy type 'nope'"),
    "unknown key": (lambda p: _edit_config(p, bogus=1), r"config\.json: .*bogus"),
    "oversized config": (lambda p: (p / "config.json").write_text(" " * (2 << 20)),
                         r"config\.json: [\d,]+ bytes, more than"),
    "garbage processor": (lambda p: (p / "processor.json").write_text("{"),
                          r"processor\.json: not valid JSON"),
    "truncated weights": (lambda p: _truncate(p / "model.safetensors"),
                          r"model\.safetensors: .*(truncated|not a safetensors)"),
    "pickle as safetensors": (lambda p: (p / "model.safetensors").write_bytes(
        pickle.dumps({"w": list(range(100))})), r"model\.safetensors: not a safetensors file"),
    "other shapes": (lambda p: _edit_config(p, dim=48),
                     r"model\.safetensors: tensor .* the model of config\.json has"),
}


@pytest.mark.parametrize("damage", list(DAMAGES))
def test_load_policy_refuses_in_one_line_naming_the_file(ckpt, damage):
    change, pattern = DAMAGES[damage]
    change(ckpt)
    with pytest.raises(CheckpointError, match=pattern) as err:
        load_policy(ckpt)
    assert "\n" not in str(err.value) and str(ckpt) in str(err.value)


def test_the_limit_is_overridable(ckpt, monkeypatch):
    assert load_policy(ckpt).config.dim == 32
    with pytest.raises(CheckpointError, match="more than the limit of 1,000"):
        load_policy(ckpt, max_params=1000)
    monkeypatch.setenv("MSTA_MAX_PARAMS", "1000")
    with pytest.raises(CheckpointError, match="MSTA_MAX_PARAMS"):
        load_policy(ckpt)
    assert load_policy(ckpt, max_params=10**7).config.dim == 32


def test_resume_from_a_damaged_checkpoint_is_one_line(synthetic_dataset, tmp_path):
    from msta.train.offline import main

    args = [f"--dataset={synthetic_dataset}", f"--output_dir={tmp_path / 'run'}",
            "--policy.preset=tiny", "--policy.input_sensors=[command,joint_pos,gravity]",
            "--batch_size=8", "--progress=false", "--device=cpu", "--steps=2"]
    main(args)
    weights = tmp_path / "run" / "checkpoints" / "last" / "pretrained_model" / "model.safetensors"
    _truncate(weights)
    with pytest.raises(SystemExit, match=r"msta-train: error: .*model\.safetensors: "):
        main([*args, "--steps=4", "--resume=true"])

"""msta's commands take a LeRobot checkpoint of ``--policy.type=msta`` (lerobot-train's
``pretrained_model/``) wherever they take an msta one (``policies/lerobot_checkpoint.py``),
with the same actions; other LeRobot checkpoints fail in one line."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from lerobot.utils.constants import POLICY_PREPROCESSOR_DEFAULT_NAME
from msta_test_helpers import hub_as, record_gait, tiny_student

from lerobot_policy_msta.convert import msta_to_lerobot
from msta.data.sensors import STUDENT_SENSORS
from msta.data.windows import WindowDataset
from msta.eval.eval_config import EvalConfig
from msta.eval.evaluate import main as eval_main
from msta.eval.evaluation import evaluate
from msta.policies.checkpoint import LEROBOT_PREPROCESSOR, CheckpointError
from msta.policies.config import PolicyConfig
from msta.policies.export_cli import main as export_main
from msta.policies.factory import load_config, load_policy
from msta.policies.lerobot_checkpoint import as_msta_checkpoint
from msta.policies.registry import get_policy_class
from msta.policies.teacher.config import TeacherConfig
from msta.train.guard_fit import main as guard_main


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """Two 2-second gait-teacher episodes recorded in the real simulator."""
    return record_gait(tmp_path_factory.mktemp("lerobot_ckpt_data") / "dataset", 2, 2.0)


@pytest.fixture(scope="module")
def ckpts(recorded, tmp_path_factory) -> tuple[Path, Path]:
    """(an msta checkpoint, the same student as a LeRobot checkpoint with a guard fitted
    into it by msta-guard)."""
    tmp = tmp_path_factory.mktemp("lerobot_ckpts")
    native = tiny_student("msta", {}, recorded).save_pretrained(tmp / "ckpt")
    threads = torch.get_num_threads()
    lerobot = msta_to_lerobot(native, tmp / "lerobot")  # builds LeRobot's policy: threads
    torch.set_num_threads(threads)
    guard_main(["fit", f"--dataset={recorded}", f"--output_dir={lerobot}"])
    return native, lerobot


def test_msta_loaders_read_a_lerobot_checkpoint(ckpts, recorded):
    native, lerobot = ckpts
    assert LEROBOT_PREPROCESSOR == f"{POLICY_PREPROCESSOR_DEFAULT_NAME}.json"
    assert load_config(lerobot) == PolicyConfig.load(native)  # msta's fields only
    with pytest.raises(CheckpointError, match="is a LeRobot checkpoint: read its config with"):
        PolicyConfig.load(lerobot)
    batch = WindowDataset(recorded, STUDENT_SENSORS, T=4).get_batch(np.arange(0, 200, 3))
    torch.manual_seed(0)
    want = load_policy(native).act(batch)
    for policy in (load_policy(lerobot), get_policy_class("msta").from_pretrained(lerobot)):
        torch.manual_seed(0)
        assert torch.equal(policy.act(batch), want)
    made = as_msta_checkpoint(lerobot, get_policy_class)
    assert as_msta_checkpoint(lerobot, get_policy_class) == made and made != lerobot  # made once per process
    assert (made / "model.safetensors").resolve() == (lerobot / "model.safetensors").resolve()
    assert (made / "guard.json").is_file() and (made / "processor.json").is_file()


def test_msta_eval_export_and_finetune_take_a_lerobot_checkpoint(ckpts, recorded, tmp_path,
                                                                 capsys):
    from msta.policies.checkpoint import PolicyPath
    from msta.train.finetune_config import FinetuneConfig
    from msta.train.finetune_run import check_source

    native, lerobot = ckpts
    export_main([f"--policy={lerobot}", f"--output_dir={tmp_path / 'export'}",
                 f"--dataset={recorded}", "--history=4", "--parity_windows=8",
                 "--random_windows=4"])
    assert "with its guard" in capsys.readouterr().out  # msta-guard wrote into it
    assert (tmp_path / "export" / "guard.json").is_file()
    metrics = evaluate(EvalConfig(
        policies=f"{native},{lerobot}", scenarios="token_removal", trials=2, suite="quick",
        terrains="flat", levels="0", episode_length_s=0.5, progress=False,
        output_dir=str(tmp_path / "eval"), teacher=TeacherConfig(type="gait")))
    runs = {}
    for r in metrics["runs"]:
        runs.setdefault(r["condition"], []).append(r["raw"])
    assert len(runs) > 1 and all(a == b for a, b in runs.values())  # the same student
    ckpt, kept = check_source(FinetuneConfig(policy=PolicyPath(str(lerobot)),
                                             dataset=str(recorded), sensors="all"))
    assert ckpt == lerobot and kept == tuple(PolicyConfig.load(native).input_sensors)


def test_a_pushed_lerobot_checkpoint_loads_by_hub_id(ckpts, recorded, tmp_path, monkeypatch):
    """msta-hub push uploads lerobot-train's pretrained_model as it is; msta's loaders take
    its hub id (real server over HTTP)."""
    from msta.data.hub_cli import main as hub_main

    native, lerobot = ckpts
    with hub_as(tmp_path / "hub", monkeypatch):
        monkeypatch.setenv("HF_HOME", str(tmp_path / "hf"))  # pulls stay in tmp_path
        monkeypatch.setenv("MSTA_HUB_CACHE", str(tmp_path / "cache"))
        assert hub_main(["push", str(lerobot), "alice/lerobot_msta", "--tag", "v1"]) == 0
        batch = WindowDataset(recorded, STUDENT_SENSORS, T=4).get_batch(np.arange(0, 200, 7))
        torch.manual_seed(0)
        want = load_policy(native).act(batch)
        torch.manual_seed(0)
        assert torch.equal(load_policy("alice/lerobot_msta@v1").act(batch), want)


def broken(lerobot: Path, dst: Path, edit) -> Path:
    out = shutil.copytree(lerobot, dst)
    edit(out)
    return out


def test_other_lerobot_checkpoints_fail_in_one_line(ckpts, tmp_path, capsys):
    _, lerobot = ckpts

    def act(d: Path) -> None:
        cfg = json.loads((d / "config.json").read_text())
        (d / "config.json").write_text(json.dumps({**cfg, "type": "act"}))

    def eps(d: Path) -> None:
        spec = json.loads((d / LEROBOT_PREPROCESSOR).read_text())
        next(s for s in spec["steps"] if s["registry_name"] == "normalizer_processor")[
            "config"]["eps"] = 1e-8
        (d / LEROBOT_PREPROCESSOR).write_text(json.dumps(spec))

    def no_stats(d: Path) -> None:
        for f in d.glob("policy_preprocessor_*normalizer_processor.safetensors"):
            f.unlink()

    def state_file(name: str):
        def edit(d: Path) -> None:
            spec = json.loads((d / LEROBOT_PREPROCESSOR).read_text())
            step = next(s for s in spec["steps"] if s["registry_name"] == "normalizer_processor")
            if name == "LINK":  # a link beside the others, leading out of the checkpoint
                secret = tmp_path / "outside.safetensors"
                shutil.copy(d / step["state_file"], secret)
                (d / "link.safetensors").symlink_to(secret)
                step["state_file"] = "link.safetensors"
            else:
                step["state_file"] = name.replace("ABS", str(d / step["state_file"]))
            (d / LEROBOT_PREPROCESSOR).write_text(json.dumps(spec))
        return edit

    run = tmp_path / "run" / "checkpoints" / "last"
    run.parent.mkdir(parents=True)
    shutil.copytree(lerobot, run / "pretrained_model")
    cases = [(broken(lerobot, tmp_path / "act", act), "is a LeRobot 'act' policy checkpoint; "
              "msta's tools load msta students"),
             (broken(lerobot, tmp_path / "eps", eps), "normalizer_processor has eps=1e-08"),
             (broken(lerobot, tmp_path / "nostats", no_stats), "missing or larger than"),
             (broken(lerobot, tmp_path / "abs", state_file("ABS")),
              f"state_file '{tmp_path}/abs/policy_pre"),
             (broken(lerobot, tmp_path / "up", state_file("../../x.safetensors")),
              "state_file '../../x.safetensors' must be a file name in the checkpoint folder"),
             (broken(lerobot, tmp_path / "link", state_file("LINK")),
              "a symbolic link leading outside the checkpoint"),
             (tmp_path / "run", "is a lerobot-train run directory; its last checkpoint is "
              f"{run / 'pretrained_model'}")]
    for path, message in cases:
        with pytest.raises(CheckpointError, match=message):
            load_policy(path)
        with pytest.raises(SystemExit):
            eval_main(["--policies", str(path), "--output_dir", str(tmp_path / "e")])
        err = capsys.readouterr().err.strip()
        assert err.startswith("msta-eval: error: ") and "\n" not in err and message in err
    with pytest.raises(CheckpointError, match="LeRobot 'act' policy"):
        load_config(tmp_path / "act")  # msta-correct / msta-finetune read it first


def test_lerobot_train_checkpoints_are_named_by_run_and_step(tmp_path):
    """msta-eval's tables name lerobot-train's pretrained_model folders <run>@<step> (they
    were all 'pretrained_model', then 'pretrained_model#2')."""
    from msta.eval.evaluation import local_name

    for run in ("run_a", "run_b"):
        step = tmp_path / run / "checkpoints" / "000003" / "pretrained_model"
        step.mkdir(parents=True)
        (tmp_path / run / "checkpoints" / "last").symlink_to("000003")
    assert local_name(tmp_path / "run_a/checkpoints/last/pretrained_model") == "run_a@000003"
    assert local_name(tmp_path / "run_b/checkpoints/000003/pretrained_model") == "run_b@000003"
    (tmp_path / "mine" / "pretrained_model").mkdir(parents=True)
    assert local_name(tmp_path / "mine" / "pretrained_model") == "mine"
    assert local_name(tmp_path / "run_a") == "run_a"  # any other folder: its own name

"""lerobot_policy_msta: the MSTA student as LeRobot's ``--policy.type=msta`` (config, processors,
checkpoint conversion both ways, and lerobot-train / lerobot-eval in subprocesses)."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from lerobot.configs import PreTrainedConfig
from lerobot.policies.factory import get_policy_class, make_pre_post_processors

from lerobot_policy_msta import MSTAConfig  # installed by the Makefile's venv step
from lerobot_policy_msta.configuration_msta import PRESET_FIELDS, state_layout
from lerobot_policy_msta.convert import checkpoint_format, lerobot_to_msta, main, msta_to_lerobot
from lerobot_policy_msta.history import STATE_PAD
from lerobot_policy_msta.modeling_msta import MSTAPolicy
from lerobot_policy_msta.processor_msta import make_msta_pre_post_processors
from msta.data import derived
from msta.data.sensors import SENSORS, STUDENT_SENSORS
from msta.data.stats import load_stats
from msta.data.windows import WindowDataset
from msta.policies.factory import load_policy, make_policy
from msta.policies.msta import PRESETS
from msta.policies.msta import MSTAConfig as NativeMSTAConfig
from msta.policies.msta import MSTAPolicy as NativeMSTAPolicy
from msta.policies.registry import make_config
from msta.train.optim import WarmupCosine, make_optimizer

BIN = Path(sys.executable).parent
TINY = {"dim": 32, "num_layers": 1, "num_heads": 2, "head_hidden_dim": 32, "history": 4}
STATE_NAMES = derived.features([s.column for s in SENSORS.values()])[derived.STATE_COLUMN]["names"]


def offline_env(tmp_path: Path) -> dict[str, str]:
    """Environment of a lerobot subprocess: offline, caches under tmp_path."""
    return {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1",
            "WANDB_MODE": "disabled", "HF_HOME": str(tmp_path / "hf"),
            "HF_LEROBOT_HOME": str(tmp_path / "lerobot"), "TORCH_HOME": str(tmp_path / "torch")}


def run(args: list[str], tmp_path: Path) -> subprocess.CompletedProcess:
    proc = subprocess.run(args, env=offline_env(tmp_path), capture_output=True, text=True,
                          timeout=300, check=False)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc


@pytest.fixture(autouse=True)
def keep_threads():
    """A policy built for a dataset sets torch's threads; the other tests keep theirs."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


# ----- config ----------------------------------------------------------------------------
def test_config_is_msta_config_plus_lerobot():
    cfg = MSTAConfig(device="cpu")
    native = {f.name: f.default for f in dataclasses.fields(NativeMSTAConfig)}
    ours = {f.name: f.default for f in dataclasses.fields(MSTAConfig) if f.name in native}
    assert set(ours) == set(native)  # every msta field
    # the preset's fields are None (filled from --policy.preset), the others msta's defaults
    assert sorted(k for k, v in ours.items() if v is None) == sorted(
        {k for p in PRESETS.values() for k in p}) == list(PRESET_FIELDS)
    assert {k: v for k, v in ours.items() if v is not None} == {
        k: v for k, v in native.items() if k not in PRESET_FIELDS}
    assert cfg.type == "msta" and get_policy_class("msta") is MSTAPolicy
    assert cfg.observation_delta_indices is None  # one frame a sample; history.py windows
    assert cfg.to_native() == NativeMSTAConfig()
    assert state_layout(STATE_NAMES) == STUDENT_SENSORS
    with pytest.raises(ValueError, match=r"sensor 'command' at channel 0: expected"):
        state_layout(["command.vx", "command.wz"])
    with pytest.raises(ValueError, match=r"input sensors \['command'\] are not in"):
        MSTAConfig(device="cpu", state_sensors=tuple(s for s in STUDENT_SENSORS
                                                     if s != "command"))
    with pytest.raises(ValueError, match="num_heads"):  # msta's own checks run
        MSTAConfig(device="cpu", dim=30, num_heads=4)


def test_training_recipe_is_msta_trains():
    cfg = MSTAConfig(device="cpu", **TINY)
    policy = MSTAPolicy(cfg)
    ours = [[id(p) for p in g["params"]] for g in policy.get_optim_params()]
    theirs = [[id(p) for p in g["params"]] for g in make_optimizer(policy, 1e-3, 0.01).param_groups]
    assert ours == theirs and len(ours[1]) > 0  # decay / no-decay groups of msta-train
    sched = cfg.get_scheduler_preset().build(torch.optim.SGD(policy.parameters(), lr=1.0), 300)
    want = WarmupCosine(100, 300, 0.1)
    assert [sched.lr_lambdas[0](s) for s in range(0, 300, 7)] == [want(s) for s in range(0, 300, 7)]
    opt = cfg.get_optimizer_preset()
    assert (opt.lr, opt.weight_decay, opt.grad_clip_norm) == (1e-3, 0.01, 1.0)


def test_processors_refuse_missing_statistics(synthetic_dataset):
    cfg = MSTAConfig(device="cpu", **TINY)
    with pytest.raises(KeyError, match="needs the dataset statistics"):
        make_msta_pre_post_processors(cfg, None)
    stats = load_stats(synthetic_dataset)
    del stats["action"]
    with pytest.raises(KeyError, match="no column 'action' .needed for the action target"):
        make_msta_pre_post_processors(cfg, stats)


def test_preset_fills_the_fields_not_given():
    cpu = MSTAConfig(device="cpu", preset="cpu")
    assert cpu.to_native() == NativeMSTAConfig.from_preset("cpu")
    assert MSTAConfig(device="cpu", preset="cpu", dim=128).to_native() == \
        NativeMSTAConfig.from_preset("cpu", dim=128)  # a field given wins over the preset
    with pytest.raises(ValueError, match=r"unknown msta preset 'gpu'; known presets: \['cpu'"):
        MSTAConfig(device="cpu", preset="gpu")


def test_threads_default_to_half_the_cores():
    cores = len(os.sched_getaffinity(0))
    assert MSTAConfig(device="cpu").cpu_threads() == max(1, cores // 2)
    with pytest.raises(ValueError, match="num_threads must be >= 0"):
        MSTAConfig(device="cpu", num_threads=-1)
    torch.set_num_threads(cores)
    MSTAPolicy(MSTAConfig(device="cpu", **TINY))
    assert torch.get_num_threads() == max(1, cores // 2)
    MSTAPolicy(MSTAConfig(device="cpu", num_threads=3, **TINY))
    assert torch.get_num_threads() == 3


# ----- windows from msta's reader ---------------------------------------------------------
def collate(ds, idx: list[int]) -> dict:
    return torch.utils.data.default_collate([ds[i] for i in idx])


def test_history_step_gives_lerobots_own_windows(synthetic_dataset):
    """lerobot-train loads one frame per sample; the preprocessor's windows are those LeRobot's
    delta_timestamps would load, bit for bit (episode starts padded alike), also for a subset
    of episodes (absolute indices)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
    from lerobot.policies.factory import make_policy as lerobot_make_policy

    meta = LeRobotDatasetMetadata("local/train_test", root=synthetic_dataset)
    cfg = MSTAConfig(device="cpu", **TINY)
    lerobot_make_policy(cfg, ds_meta=meta)  # attaches the dataset, as in lerobot-train
    pre, _ = make_pre_post_processors(cfg, dataset_stats=meta.stats)
    deltas = {derived.STATE_COLUMN: [i / meta.fps for i in range(1 - cfg.history, 1)]}
    for episodes, idx in ((None, [0, 1, 2, 3, 5, 39, 40, 41, 200, 479]), ([3, 7], [0, 2, 41])):
        plain = LeRobotDataset("local/train_test", root=synthetic_dataset, episodes=episodes)
        windowed = LeRobotDataset("local/train_test", root=synthetic_dataset,
                                  episodes=episodes, delta_timestamps=deltas)
        got, want = pre(collate(plain, idx)), pre(collate(windowed, idx))
        assert got[derived.STATE_COLUMN].shape == (len(idx), cfg.history, 49)
        assert torch.equal(got[derived.STATE_COLUMN], want[derived.STATE_COLUMN])
        assert torch.equal(got[STATE_PAD], want[STATE_PAD]) and got[STATE_PAD].any()


def test_history_step_refuses_what_it_cannot_window(synthetic_dataset, monkeypatch):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata

    from lerobot_policy_msta import history

    meta = LeRobotDatasetMetadata("local/train_test", root=synthetic_dataset)
    cfg = MSTAConfig(device="cpu", **TINY)
    policy = MSTAPolicy(cfg, dataset_meta=meta)
    pre, _ = make_pre_post_processors(cfg, dataset_stats=meta.stats)
    batch = collate(LeRobotDataset("local/train_test", root=synthetic_dataset), [0, 7])
    wrong = {**batch, derived.STATE_COLUMN: batch[derived.STATE_COLUMN] + 1.0}
    with pytest.raises(ValueError, match="is not the frames its 'index' names in the dataset"):
        pre(wrong)
    with pytest.raises(ValueError, match=r"msta trains on T-step windows .B, T, D.; run the"):
        policy.forward({derived.STATE_COLUMN: batch[derived.STATE_COLUMN],
                        "action": batch["action"]})  # not preprocessed: no windows
    monkeypatch.setattr(history, "_ATTACHED", [])
    with pytest.raises(ValueError, match="no dataset is attached for T = 4: build MSTAPolicy"):
        pre(batch)
    state = batch[derived.STATE_COLUMN]  # an environment's observation has no index
    assert pre({derived.STATE_COLUMN: state})[derived.STATE_COLUMN].shape == state.shape


# ----- conversion --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def native_ckpt(synthetic_dataset, tmp_path_factory) -> Path:
    torch.manual_seed(0)
    policy = make_policy(make_config("msta", **TINY), load_stats(synthetic_dataset))
    return policy.save_pretrained(tmp_path_factory.mktemp("native") / "ckpt")


def windows(root: Path, T: int = 4) -> dict[str, np.ndarray]:
    """Raw windows of the first 60 frames (episode starts included, so some steps are pads)."""
    return WindowDataset(root, STUDENT_SENSORS, T=T).get_batch(np.arange(60))


def lerobot_actions(ckpt: Path, batch: dict[str, np.ndarray]) -> torch.Tensor:
    """Raw actions of a LeRobot checkpoint through LeRobot's own loaders and processors."""
    cfg = PreTrainedConfig.from_pretrained(ckpt)
    policy = get_policy_class(cfg.type).from_pretrained(ckpt, config=cfg)
    pre, post = make_pre_post_processors(cfg, pretrained_path=str(ckpt))
    state = np.concatenate([batch[s] for s in STUDENT_SENSORS], axis=-1)  # observation.state
    obs = pre({derived.STATE_COLUMN: torch.as_tensor(state),
               f"{derived.STATE_COLUMN}_is_pad": torch.as_tensor(batch["pad"])})
    torch.manual_seed(0)  # padded tokens are removed in a random order, as in msta
    return post(policy.predict_action_chunk(obs)[:, 0])


def msta_actions(ckpt: Path, batch: dict[str, np.ndarray]) -> torch.Tensor:
    torch.manual_seed(0)
    return load_policy(ckpt).act(batch)


def test_conversion_round_trips_actions_exactly(synthetic_dataset, native_ckpt, tmp_path):
    batch = windows(synthetic_dataset)
    assert batch["pad"].any()
    want = msta_actions(native_ckpt, batch)
    assert checkpoint_format(native_ckpt) == "msta"
    lr = msta_to_lerobot(native_ckpt, tmp_path / "lerobot")
    assert checkpoint_format(lr) == "lerobot"
    assert torch.equal(lerobot_actions(lr, batch), want)
    back = lerobot_to_msta(lr, tmp_path / "msta")
    assert torch.equal(msta_actions(back, batch), want)
    again = msta_to_lerobot(back, tmp_path / "lerobot2")
    assert torch.equal(lerobot_actions(again, batch), want)
    with pytest.raises(FileExistsError, match="not empty"):
        msta_to_lerobot(native_ckpt, tmp_path / "lerobot")


def test_native_checkpoint_loads_through_lerobots_api(native_ckpt):
    """config.json and model.safetensors of msta load as they are (strictly); inference
    through LeRobot also needs the converted processors."""
    cfg = PreTrainedConfig.from_pretrained(native_ckpt)
    assert isinstance(cfg, MSTAConfig) and cfg.to_native() == load_policy(native_ckpt).config
    policy = MSTAPolicy.from_pretrained(native_ckpt, config=cfg)
    native = NativeMSTAPolicy.from_pretrained(native_ckpt)
    for k, v in native.state_dict().items():
        assert torch.equal(policy.state_dict()[k], v), k


def test_select_action_keeps_msta_actors_history(synthetic_dataset, native_ckpt, tmp_path):
    """Step by step, LeRobot's select_action sees what msta's StudentActor sees."""
    from msta.policies.actor import StudentActor

    lr = msta_to_lerobot(native_ckpt, tmp_path / "lerobot")
    cfg = PreTrainedConfig.from_pretrained(lr)
    policy = MSTAPolicy.from_pretrained(lr, config=cfg)
    pre, post = make_pre_post_processors(cfg, pretrained_path=str(lr))
    actor = StudentActor(load_policy(native_ckpt), num_envs=3)
    frames = WindowDataset(synthetic_dataset, STUDENT_SENSORS, T=1).get_batch(np.arange(18))
    policy.reset()
    for t in range(6):  # 3 robots, 6 steps (frames t, 6 + t, 12 + t)
        obs = {s: frames[s][[t, 6 + t, 12 + t], 0] for s in STUDENT_SENSORS}
        want = torch.as_tensor(actor.act(obs))
        state = np.concatenate([obs[s] for s in STUDENT_SENSORS], axis=-1)
        got = post(policy.select_action(pre({derived.STATE_COLUMN: torch.as_tensor(state)})))
        torch.testing.assert_close(got, want, atol=1e-5, rtol=1e-5)


def test_convert_command_line(native_ckpt, tmp_path, capsys):
    main([f"--policy.path={native_ckpt}", f"--output_dir={tmp_path / 'out'}"])
    assert "-> LeRobot checkpoint" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="neither an msta checkpoint"):
        main([f"--policy.path={tmp_path}", f"--output_dir={tmp_path / 'x'}"])


# ----- the lerobot commands ---------------------------------------------------------------
def test_lerobot_lists_the_plugins(tmp_path):
    proc = run([str(BIN / "lerobot-train"), "--help"], tmp_path)
    help_text = proc.stdout
    # at most one line about the video decoder (where torchcodec cannot load), no traceback
    codec = [line for line in proc.stderr.splitlines() if "torchcodec" in line.lower()]
    assert len(codec) <= 1 and "Traceback" not in proc.stderr, proc.stderr[:2000]
    policy_types = next(line for line in help_text.splitlines() if "--policy.type {" in line)
    env_types = next(line for line in help_text.splitlines() if "--env.type {" in line)
    assert "msta" in policy_types.split("{")[1].split("}")[0].split(",")
    assert "msta_a1" in env_types.split("{")[1].split("}")[0].split(",")


@pytest.mark.parametrize("option,says", [
    ("--policy.preset=huge", "unknown msta preset 'huge'; known presets: ['cpu', 'paper', 'tiny']"),
    ("--policy.input_sensors=[lidar]", "lidar"),
])
def test_a_bad_msta_option_through_lerobot_train_says_msta_s_own_line(option, says, tmp_path):
    """draccus keeps only "Couldn't instantiate class MSTAConfig"; msta's line comes first."""
    proc = subprocess.run([str(BIN / "lerobot-train"), "--policy.type=msta", option,
                           "--dataset.repo_id=local/x", f"--dataset.root={tmp_path / 'none'}",
                           "--policy.push_to_hub=false"], env=offline_env(tmp_path),
                          capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode != 0
    mine = [line for line in proc.stderr.splitlines() if line.startswith("msta policy: error: ")]
    assert len(mine) == 1 and says in mine[0], proc.stderr[-2000:]


@pytest.fixture(scope="module")
def lerobot_trained(synthetic_dataset, tmp_path_factory) -> Path:
    """A few lerobot-train steps of the tiny MSTA student on an msta dataset."""
    tmp = tmp_path_factory.mktemp("lerobot_train")
    out = tmp / "out"
    proc = run([str(BIN / "lerobot-train"), "--policy.type=msta",
                "--dataset.repo_id=local/train_test", f"--dataset.root={synthetic_dataset}",
                "--policy.device=cpu", "--steps=3", "--batch_size=4", "--num_workers=0",
                "--save_freq=3", "--log_freq=1", f"--output_dir={out}", "--policy.preset=tiny",
                "--policy.history=4", "--policy.num_threads=1"], tmp)
    (out / "train.log").write_text(proc.stdout + proc.stderr)
    return out / "checkpoints" / "last" / "pretrained_model"


def test_lerobot_train_trains_msta(lerobot_trained, synthetic_dataset, tmp_path):
    config = json.loads((lerobot_trained / "config.json").read_text())
    assert config["type"] == "msta" and config["history"] == 4 and config["preset"] == "tiny"
    assert {k: config[k] for k in PRESETS["tiny"]} == PRESETS["tiny"]  # from --policy.preset
    log = (lerobot_trained.parents[2] / "train.log").read_text()
    assert len(re.findall(r"step:\d+ .*loss:\d", log)) == 3  # --log_freq=1: a loss line a step
    assert config["state_sensors"] == list(STUDENT_SENSORS)  # read from the feature names
    assert set(config["input_features"]) == {derived.STATE_COLUMN}
    train_cfg = json.loads((lerobot_trained / "train_config.json").read_text())
    assert train_cfg["scheduler"]["type"] == "msta_warmup_cosine"
    assert train_cfg["optimizer"]["grad_clip_norm"] == 1.0
    batch = windows(synthetic_dataset)
    native = lerobot_to_msta(lerobot_trained, tmp_path / "msta")
    got = lerobot_actions(lerobot_trained, batch)
    assert torch.isfinite(got).all() and torch.equal(got, msta_actions(native, batch))


def test_msta_export_checks_parity_on_the_dataset_lerobot_train_named(lerobot_trained,
                                                                      synthetic_dataset,
                                                                      tmp_path, capsys):
    """train_config.json's dataset (LeRobot's {"repo_id", "root"}) gives the recorded
    windows, as msta-train's does; no --dataset needed."""
    from msta.policies.export_cli import main as export_main

    export_main([f"--policy={lerobot_trained}", f"--output_dir={tmp_path / 'export'}",
                 "--parity_windows=8", "--random_windows=2"])
    assert "no dataset found" not in capsys.readouterr().err
    spec = json.loads((tmp_path / "export" / "spec.json").read_text())
    assert spec["source"]["dataset"] == str(synthetic_dataset)
    assert {p["windows"] for p in spec["parity"]} >= {"recorded", "random"}


def test_lerobot_train_resumes_with_msta_windows(lerobot_trained, tmp_path):
    """--resume loads the preprocessor from the checkpoint; its history step still finds the
    dataset (the policy built for it registers it) and the run continues with loss lines."""
    run_dir = shutil.copytree(lerobot_trained.parents[2], tmp_path / "run", symlinks=True)
    proc = run([str(BIN / "lerobot-train"), "--resume=true", f"--output_dir={run_dir}",
                f"--config_path={run_dir / 'checkpoints/last/pretrained_model/train_config.json'}",
                "--steps=5"], tmp_path)
    assert re.findall(r"step:(\d+) .*loss:\d", proc.stdout + proc.stderr) == ["4", "5"]
    assert (run_dir / "checkpoints" / "000005" / "pretrained_model").is_dir()


def test_lerobot_eval_runs_the_trained_student(lerobot_trained, tmp_path):
    out = tmp_path / "eval"
    proc = run([str(BIN / "lerobot-eval"), "--env.type=msta_a1",
                f"--policy.path={lerobot_trained}", "--eval.n_episodes=2", "--eval.batch_size=2",
                "--env.terrains=[flat]", "--env.episode_length_s=0.2", "--env.video=false",
                "--eval.recording=true", f"--output_dir={out}"], tmp_path)
    assert "Overall Aggregated Metrics" in proc.stdout + proc.stderr
    info = json.loads((out / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 2 and np.isfinite(info["overall"]["avg_sum_reward"])
    assert not list(out.rglob("*.mp4"))  # video off and recording: no blank videos


def test_compare_trainers_times_both_trainers_alike():
    from lerobot_policy_msta.compare_trainers import (
        CompareTrainersConfig,
        lerobot_steps_per_s,
        speed_line,
    )

    log = "\n".join(f"INFO x step:{n} smpl:{16 * n} loss:0.9 updt_s:{u} data_s:0.020 smp/s:99"
                    for n, u in ((50, 9.0), (100, 0.080), (150, 0.180)))
    assert lerobot_steps_per_s(log, warmup=50) == pytest.approx(1 / 0.15)  # warm-up left out
    cfg = CompareTrainersConfig(dataset="x", steps=200, log_freq=50)
    records = [{"msta_train": {"steps_per_s": 10.0}, "lerobot_train": {"steps_per_s": s}}
               for s in (8.0, 9.0)]
    assert speed_line(records, cfg).startswith("lerobot-train / msta-train steps/s: 0.85 (")
    with pytest.raises(ValueError, match="at least 2 x log_freq"):
        CompareTrainersConfig(dataset="x", steps=60, log_freq=50)


def test_documented_plugin_commands_parse():
    """Every ``python -m lerobot_policy_msta.*`` line of README.md and docs/ parses (the docs
    check of tests/test_docs_commands.py covers msta's own commands)."""
    import shlex

    from lerobot_policy_msta.compare_trainers import CompareTrainersConfig
    from lerobot_policy_msta.convert import ConvertConfig
    from msta.data.cli import parse_config

    repo = Path(__file__).resolve().parents[2]
    configs = {"convert": ConvertConfig, "compare_trainers": CompareTrainersConfig}
    found = []
    for path in [repo / "README.md", *sorted((repo / "docs").glob("*.md"))]:
        text = re.sub(r"\\\n\s*", " ", path.read_text())  # continuation lines joined
        for m in re.finditer(r"python -m lerobot_policy_msta\.(\w+)([^`#\n]*)", text):
            found.append(m.group(1))
            parse_config(configs[m.group(1)], shlex.split(m.group(2)), m.group(1))
    assert {"convert", "compare_trainers"} <= set(found)

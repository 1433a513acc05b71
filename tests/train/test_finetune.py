"""msta-finetune: msta-correct rounds on a minimized observation with a frozen transformer."""

from __future__ import annotations

import hashlib
import json
import re
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from msta.collect.record import CollectConfig, collect
from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.data import sensors
from msta.data.budget import TimeLimitReached
from msta.data.stats import load_stats
from msta.data.windows import WindowDataset, load_episode_table
from msta.policies.actor import StudentActor
from msta.policies.baselines.configs import GRUConfig
from msta.policies.checkpoint import PolicyPath
from msta.policies.factory import load_policy, make_policy
from msta.policies.input_spec import MINIMIZED_SENSORS, InputSpec
from msta.policies.msta import MSTAConfig
from msta.policies.teacher.config import TeacherConfig
from msta.train.correct_config import RoundEvalConfig
from msta.train.finetune import main
from msta.train.finetune_config import FinetuneConfig, trainable_modules
from msta.train.finetune_run import RECORD, Preparation, finetune, freeze
from msta.train.optim import make_optimizer

TERRAIN = TerrainConfig(types=("flat", "stairs_up"), num_levels=2, max_init_level=1,
                        border=2.0)
E = 4  # episodes per round
EPISODE_S = 0.3
#: the deployment observation in the checkpoint's (the registry's) order
KEPT = tuple(s for s in sensors.STUDENT_SENSORS if s in MINIMIZED_SENSORS)


def small_env() -> EnvConfig:
    return EnvConfig(nthread=1, terrain=TERRAIN, randomization=RandomizationConfig(pool_size=2))


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> tuple[Path, Path, Path]:
    """(teacher dataset, tiny MSTA checkpoint trained at T = 5, tiny GRU checkpoint)."""
    d = tmp_path_factory.mktemp("finetune")
    root = collect(CollectConfig(teacher=TeacherConfig(type="gait"), episodes=4, num_envs=4,
                                 root=str(d / "ds"), episode_length_s=EPISODE_S,
                                 progress=False, env=small_env()))
    torch.manual_seed(0)
    msta = make_policy(MSTAConfig.from_preset("tiny", history=5), load_stats(root))
    gru = make_policy(GRUConfig.from_preset("tiny"), load_stats(root))
    return root, msta.save_pretrained(d / "msta"), gru.save_pretrained(d / "gru")


def make_cfg(base, out: Path, **kw) -> FinetuneConfig:
    defaults = {"policy": PolicyPath(str(base[1])), "dataset": str(base[0]),
                "output_dir": str(out), "rounds": 1, "episodes_per_round": E,
                "num_envs": 4, "episode_length_s": EPISODE_S, "env": small_env(),
                "teacher": TeacherConfig(type="gait"), "steps": 4, "batch_size": 8,
                "warmup_steps": 1, "lr": 3e-2, "progress": False, "device": "cpu",
                "eval": RoundEvalConfig(enabled=False)}
    return FinetuneConfig(**{**defaults, **kw})


@pytest.fixture(scope="module")
def one_round(base, tmp_path_factory) -> tuple[FinetuneConfig, dict]:
    """A one-round fine-tune evaluated at test mask 0 (4 trials of 1 s)."""
    import shutil

    tmp = tmp_path_factory.mktemp("one_round")
    shutil.copytree(base[0], tmp / "ds")
    cfg = make_cfg(base, tmp / "out", dataset=str(tmp / "ds"),
                   eval=RoundEvalConfig(trials=4, episode_length_s=1.0, terrains="flat", levels="0",
                                   mask_ratios=(0.0,)))
    return cfg, finetune(cfg)


def tensor_hashes(directory: Path) -> dict[str, str]:
    policy = load_policy(directory)
    return {k: hashlib.sha256(v.detach().contiguous().numpy().tobytes()).hexdigest()
            for k, v in policy.state_dict().items()}


def test_only_the_trainable_embeddings_change(base, one_round):
    cfg, _ = one_round
    out = Path(cfg.output_dir)
    record = json.loads((out / "round_1" / RECORD).read_text())
    trained = set(record["trained_parameters"])
    assert {re.sub(r"\.\w+$", "", k) for k in trained} == {"model.bin_embed", "model.sensor_embed"}
    src, start, after = (tensor_hashes(d) for d in (base[1], out / "start", out / "round_1"))
    frozen = set(after) - trained
    assert any(k.startswith("model.blocks.") for k in frozen)
    assert {"model.ln_f.weight", "model.head.0.weight", "model.state_token"} <= frozen
    assert all(after[k] == src[k] == start[k] for k in frozen)  # the transformer is untouched
    assert all(after[k] != start[k] for k in trained)  # every embedding was trained
    assert set(src) - set(after) == {f"model.sensor_embed.{s}" for s in
                                     set(sensors.STUDENT_SENSORS) - set(KEPT)}


def test_the_optimizer_gets_only_the_trainable_parameters(base):
    policy = load_policy(base[1]).with_inputs(KEPT, 7)
    names = freeze(policy, trainable_modules("embeddings+head"))
    assert all(n.startswith(("model.bin_embed", "model.sensor_embed", "model.ln_f",
                             "model.head")) for n in names)
    opt = make_optimizer(policy, 1e-3, 0.01)
    params = {id(p) for g in opt.param_groups for p in g["params"]}
    assert params == {id(p) for n, p in policy.named_parameters() if n in names}


@pytest.mark.parametrize("variant", [{}, {"value_embedding": "sensor", "state_tokens": 2},
                                     {"value_embedding": "shared"}, {"learnable_mask": True}])
def test_restricted_copy_acts_as_the_source_on_the_kept_inputs(base, variant):
    """with_inputs copies the kept sensors' value tables and embeddings: the same actions
    on the same windows (the learnable-mask ablation fills the dropped sensors of the
    source with mask tokens, so there only the copy's shapes are checked)."""
    src = make_policy(MSTAConfig.from_preset("tiny", **variant), load_stats(base[0]))
    start = src.with_inputs(("gravity", "joint_pos", "command", "last_action"), 7)
    assert start.required_sensors == KEPT and start.config.history == 7
    assert set(start.processor.stats) == {sensors.get(s).column for s in KEPT} | {"action"}
    ds = WindowDataset(base[0], KEPT, 7, extra_columns=())
    batch = ds.get_batch(np.arange(0, len(ds), 7))
    if variant.get("learnable_mask"):
        assert start.act(batch).shape == (len(batch["pad"]), 12)
        return
    torch.testing.assert_close(start.act(batch), src.act(batch), rtol=0, atol=1e-6)
    with pytest.raises(ValueError, match="no statistics for the new input 'joint_vel'"):
        start.with_inputs(("command", "joint_vel"), 7)


def test_checkpoint_records_its_observation_and_acts_on_it(base, one_round):
    cfg, prog = one_round
    out = Path(cfg.output_dir)
    ckpt = out / "round_1"
    config = json.loads((ckpt / "config.json").read_text())
    assert tuple(config["input_sensors"]) == KEPT and config["history"] == 7
    record = json.loads((ckpt / RECORD).read_text())
    assert record["input_sensors"] == list(KEPT) and record["history"] == 7
    assert record["trainable"] == "embeddings" and record["source"] == str(base[1])
    assert 0 < record["trained_numel"] < record["total_numel"]
    assert json.loads((out / "start" / RECORD).read_text()) == record
    assert prog.config["sensors"] == cfg.sensors and prog.config["history"] == 7
    # the student drove on the kept inputs; the appended episodes hold every column
    eps = load_episode_table(Path(cfg.dataset))
    assert (eps["provenance/source"] == "student").sum() == E
    WindowDataset(cfg.dataset, sensors.STUDENT_SENSORS, 7, episodes=range(4, 4 + E))
    # loads with only the kept sensors at T = 7 and acts in the simulator's batch layout
    policy = load_policy(ckpt)
    actor = StudentActor(policy, 3, InputSpec())
    assert actor.sensors == KEPT and actor.history == 7
    rng = np.random.default_rng(0)
    obs = {s: rng.standard_normal((3, sensors.get(s).dim)).astype(np.float32)
           for s in sensors.STUDENT_SENSORS}
    for _ in range(9):
        a = actor.act(obs)
    assert a.shape == (3, 12) and np.isfinite(a).all()
    with pytest.raises(ValueError, match="'joint_vel' is not an input"):
        policy.act({"joint_vel": torch.zeros(1, 7, 12)})
    # msta-correct's per-round evaluation ran start (round 0) and round 1 on that observation
    for r in (0, 1):
        assert prog.rounds[r].eval["0"]["status"] == "ok"
    assert prog.rounds[0].checkpoint == str(out / "start")


def test_bad_inputs_are_one_line_errors(base, one_round, tmp_path, capsys):
    for kw, msg in (({"sensors": "command,sonar"}, "unknown sensor 'sonar'"),
                    ({"sensors": "command,base_height"}, "privileged"),
                    ({"sensors": " , "}, "sensors is empty"),
                    ({"trainable": ""}, "trainable is empty"),
                    ({"trainable": "embeddings+blocks"}, "unknown trainable group 'blocks'"),
                    ({"history": 0}, "history=0 must be >= 1")):
        with pytest.raises(ValueError, match=msg):
            make_cfg(base, tmp_path / "out", **kw)
    with pytest.raises(SystemExit) as e:
        main(["--trainable=", f"--policy.path={base[1]}"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "msta-finetune: error:" in err and "trainable" in err
    cases = ((base[2], "", "holds a 'gru' student"),
             (base[1], "command,height_map", "does not record 'height_map'"))
    for ckpt, sensor_list, msg in cases:
        args = [f"--policy.path={ckpt}", f"--dataset={base[0]}",
                f"--output_dir={tmp_path / 'out'}", "--device=cpu"]
        args += [f"--sensors={sensor_list}"] if sensor_list else []
        with pytest.raises(SystemExit, match=msg) as e:
            main(args)
        assert len(str(e.value).splitlines()) == 1 and str(e.value).startswith("msta-finetune:")
    assert not (tmp_path / "out").exists()  # refused before anything was written
    with pytest.raises(TypeError, match="MSTA only"):
        Preparation(make_cfg(base, tmp_path / "out"), base[2], KEPT)(load_policy(base[2]), base[0])


def test_help_lists_the_options(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    text = capsys.readouterr().out
    for flag, words in (("--sensors", "command,joint_pos,gravity,last_action"),
                        ("--history", "(default: 7)"), ("--trainable", "(default: embeddings)"),
                        ("--rounds", "correction rounds"), ("--steps", "optimizer steps"),
                        ("--episodes_per_round", "student episodes"),
                        ("--output_dir", "finetune.json"), ("--resume", "continue")):
        line = re.search(rf"^  {re.escape(flag)} .*?(?=^  --|\Z)", text, re.MULTILINE | re.DOTALL)
        assert line and words in " ".join(line.group(0).split()), flag


class Kill(RuntimeError):
    pass


def test_resume_keeps_the_prepared_student_and_checks_its_options(base, tmp_path):
    """Killed after round 1 trained: the resumed run starts round 2 from round_1 (already
    minimized: preparing it again changes nothing) and refuses another --history."""

    def kill(phase: str, r: int) -> None:
        if phase == "trained":
            raise Kill

    import shutil

    shutil.copytree(base[0], tmp_path / "ds")
    cfg = make_cfg(base, tmp_path / "out", dataset=str(tmp_path / "ds"))
    with pytest.raises(Kill):
        finetune(cfg, on_phase=kill)
    out = Path(cfg.output_dir)
    assert (out / "round_1" / RECORD).is_file()  # recorded before the kill
    with pytest.raises(ValueError, match=r"different \['history'\]"):
        finetune(make_cfg(base, out, dataset=cfg.dataset, resume=True, history=5))
    round1 = tensor_hashes(out / "round_1")
    prog = finetune(make_cfg(base, out, dataset=cfg.dataset, resume=True, rounds=2))
    assert prog.rounds[2].trained and len(load_episode_table(Path(cfg.dataset))) == 4 + 2 * E
    round2 = tensor_hashes(out / "round_2")
    record = json.loads((out / "round_2" / RECORD).read_text())
    frozen = set(round2) - set(record["trained_parameters"])
    assert set(round2) == set(round1) and all(round2[k] == round1[k] for k in frozen)


def test_a_new_sensor_is_added_and_trained_with_the_embeddings(base, tmp_path):
    """--sensors naming a sensor the checkpoint lacks (the height_map extension): it joins
    the student with fresh weights and the dataset's statistics, its encoder trains with the
    embeddings, and the rounds record it."""
    root = collect(CollectConfig(teacher=TeacherConfig(type="gait"), episodes=4, num_envs=4,
                                 root=str(tmp_path / "ds"), episode_length_s=EPISODE_S,
                                 extra_sensors="height_map", progress=False, env=small_env()))
    wanted = (*MINIMIZED_SENSORS, "height_map")
    shutil.copytree(root, tmp_path / "ds2")
    cfg = make_cfg(base, tmp_path / "out", dataset=str(root), sensors=",".join(wanted))
    finetune(cfg)
    out = Path(cfg.output_dir)
    record = json.loads((out / "round_1" / RECORD).read_text())
    assert record["added_sensors"] == ["height_map"]
    assert record["input_sensors"] == [*KEPT, "height_map"]
    assert any(n.startswith("model.encoders.height_map.") for n in record["trained_parameters"])
    start, after = tensor_hashes(out / "start"), tensor_hashes(out / "round_1")
    enc = [k for k in after if k.startswith("model.encoders.height_map.")]
    assert enc and all(after[k] != start[k] for k in enc)
    assert all(after[k] == start[k] for k in after if k.startswith("model.blocks."))
    policy = load_policy(out / "round_1")
    assert policy.required_sensors == (*KEPT, "height_map")
    assert sensors.get("height_map").column in policy.processor.stats
    eps = load_episode_table(root)
    assert (eps["provenance/source"] == "student").sum() == E
    WindowDataset(root, ("height_map",), 7, episodes=range(4, 4 + E))
    # stopped by --max_minutes after round 1's append, which changed the dataset's
    # statistics: the resumed call keeps the student prepared before (its new sensor's
    # statistics too), so it ends as the uninterrupted run did
    cfg2 = make_cfg(base, tmp_path / "out2", dataset=str(tmp_path / "ds2"),
                    sensors=",".join(wanted), max_minutes=1e-9)
    with pytest.raises(TimeLimitReached, match="round 1: episodes appended"):
        finetune(cfg2)
    finetune(replace(cfg2, resume=True, max_minutes=0.0))
    for name in ("start", "round_1"):
        assert (tmp_path / "out2" / name / "processor.json").read_text() == \
            (out / name / "processor.json").read_text(), name

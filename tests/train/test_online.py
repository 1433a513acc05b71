"""msta-correct (stage 2): student rollouts labelled by the teacher, appended, retrained."""

from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from collect.record import CollectConfig, collect, record_rollouts
from collect.sim.env import EnvConfig, QuadrupedEnv
from collect.sim.randomization import RandomizationConfig
from collect.sim.terrain import TerrainConfig
from msta_data.stats import load_stats
from msta_data.windows import WindowDataset, load_episode_table
from policies.factory import make_policy
from policies.msta import MSTAConfig, MSTAPolicy
from policies.teacher.config import TeacherConfig, build_teacher
from train.online import CorrectConfig, EvalConfig, correct, main, policy_revision

TERRAIN = TerrainConfig(types=("flat", "stairs_up"), num_levels=2, max_init_level=1,
                        border=2.0)
E = 4  # episodes per round
EPISODE_S = 0.3


def small_env(**kw) -> EnvConfig:
    return EnvConfig(nthread=1, terrain=TERRAIN, randomization=RandomizationConfig(pool_size=2),
                     **kw)


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> tuple[Path, Path]:
    """(teacher dataset with 4 gait episodes, untrained tiny student checkpoint)."""
    d = tmp_path_factory.mktemp("stage2")
    root = collect(CollectConfig(teacher=TeacherConfig(type="gait"), episodes=4, num_envs=4,
                                 root=str(d / "ds"), episode_length_s=EPISODE_S,
                                 progress=False, env=small_env()))
    policy = make_policy(MSTAConfig.from_preset("tiny", history=5), load_stats(root))
    return root, policy.save_pretrained(d / "student")


def make_cfg(base, tmp_path: Path, **kw) -> CorrectConfig:
    root = tmp_path / "ds"
    if not root.exists():
        shutil.copytree(base[0], root)
    defaults = {"policy": str(base[1]), "dataset": str(root),
                "output_dir": str(tmp_path / "out"), "rounds": 2, "episodes_per_round": E,
                "num_envs": 4, "episode_length_s": EPISODE_S, "env": small_env(),
                "teacher": TeacherConfig(type="gait"), "steps": 3, "batch_size": 8,
                "warmup_steps": 1, "progress": False, "device": "cpu",
                "eval": EvalConfig(enabled=False)}
    return CorrectConfig(**{**defaults, **kw})


def file_hashes(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted((root / "data").rglob("*.parquet"))}


@pytest.fixture(scope="module")
def two_rounds(base, tmp_path_factory) -> tuple[CorrectConfig, dict, dict[str, str]]:
    """An uninterrupted two-round run: (config, progress, teacher data file hashes)."""
    tmp = tmp_path_factory.mktemp("two_rounds")
    cfg = make_cfg(base, tmp, eval=EvalConfig(env=small_env(num_envs=2, seed=7), steps=5,
                                              mask_ratios=(0.0, 0.5)))
    before = file_hashes(Path(cfg.dataset))
    return cfg, correct(cfg), before


def test_two_rounds_append_with_provenance_and_teacher_labels(base, two_rounds):
    cfg, prog, before = two_rounds
    root, out = Path(cfg.dataset), Path(cfg.output_dir)
    eps = load_episode_table(root)
    assert len(eps) == 4 + 2 * E
    old = load_episode_table(base[0])
    assert eps.iloc[:4].drop(columns=[]).equals(old)  # earlier episodes untouched
    assert all(file_hashes(root)[k] == v for k, v in before.items())
    start_rev = policy_revision(MSTAPolicy.from_pretrained(base[1]))
    round1_rev = policy_revision(MSTAPolicy.from_pretrained(out / "round_1"))
    assert round1_rev != start_rev
    for r, rev in ((1, start_rev), (2, round1_rev)):
        tail = eps.iloc[4 + (r - 1) * E: 4 + r * E]
        assert (tail["provenance/source"] == "student").all()
        assert (tail["provenance/round"] == r).all()
        assert (tail["provenance/policy"] == "msta").all()
        assert (tail["provenance/policy_revision"] == rev).all()
        assert set(tail["provenance/terrain"]) <= set(TERRAIN.types)
        assert prog["rounds"][str(r)]["policy_revision"] == rev
    assert (eps.iloc[:4]["provenance/source"] == "teacher").all()
    MSTAPolicy.from_pretrained(out / "round_2")
    # per-round evaluation against the teacher on the same seeds, both test masks
    assert set(prog["rounds"]) == {"0", "1", "2"}
    assert set(prog["rounds"]["2"]["eval"]) == {"0", "0.5"}
    assert prog["teacher_eval"]["reward_per_step"] > 0
    assert prog["rounds"]["1"]["rollout"]["env_steps_per_s"] > 0
    assert prog["rounds"]["1"]["train"]["train_samples_per_s"] > 0
    # labels: the teacher's action on the recorded (privileged) observation, replayed
    teacher = build_teacher(TeacherConfig(type="gait"))
    student_eps = list(range(4, 4 + 2 * E))
    ds = WindowDataset(root, teacher.sensors, T=1, extra_columns=("action", "executed_action"),
                       episodes=student_eps)
    b = ds.get_batch(np.arange(len(ds)))
    for start, length in zip(ds.starts, ds.lengths, strict=True):
        teacher.reset(np.array([0]))
        for t in range(start, start + length):
            a = teacher.act({s: b[s][t:t + 1, 0] for s in teacher.sensors})
            np.testing.assert_allclose(a[0], b["action"][t], rtol=1e-4, atol=1e-4)
    # the student drove (beta = 0): executed actions are not the labels
    assert not np.allclose(b["executed_action"], b["action"], atol=1e-3)


def test_beta_one_reproduces_teacher_rollouts(base, tmp_path):
    cfg = make_cfg(base, tmp_path, rounds=1, beta=1.0)
    args = [f"--policy={cfg.policy}", f"--dataset={cfg.dataset}",
            f"--output_dir={cfg.output_dir}", "--rounds=1", f"--episodes_per_round={E}",
            "--num_envs=4", f"--episode_length_s={EPISODE_S}", "--env.nthread=1",
            "--env.terrain.types=[flat,stairs_up]", "--env.terrain.num_levels=2",
            "--env.terrain.max_init_level=1", "--env.terrain.border=2.0",
            "--env.randomization.pool_size=2", "--teacher.type=gait", "--beta=1.0",
            "--steps=2", "--batch_size=8", "--warmup_steps=1", "--progress=false",
            "--device=cpu", "--eval.enabled=false"]
    main(args)
    root = Path(cfg.dataset)
    ds = WindowDataset(root, ["joint_pos"], T=1, extra_columns=("action", "executed_action"),
                       episodes=range(4, 4 + E))
    b = ds.get_batch(np.arange(len(ds)))
    np.testing.assert_array_equal(b["executed_action"], b["action"])
    # the same environments driven by the teacher alone give the same episodes
    env = QuadrupedEnv(replace(small_env(), num_envs=4, seed=cfg.env.seed + 1000,
                               episode_length_s=EPISODE_S))
    ref: list[dict[str, np.ndarray]] = []
    record_rollouts(env, build_teacher(TeacherConfig(type="gait")), E,
                    lambda f, ti, lv: ref.append(f), progress=False)
    assert [len(f["action"]) for f in ref] == list(ds.lengths)
    np.testing.assert_array_equal(np.concatenate([f["action"] for f in ref]), b["action"])
    np.testing.assert_array_equal(np.concatenate([f["observation.joint_pos"] for f in ref]),
                                  b["joint_pos"][:, 0])


class Kill(RuntimeError):
    pass


@pytest.mark.parametrize("phase", ["rolled_out", "committed"])
def test_resume_after_a_kill_between_rollout_and_retrain(base, two_rounds, tmp_path, phase):
    """Killed before the append commits, or after it but before progress.json knows."""

    def kill(p: str, r: int) -> None:
        if (p, r) == (phase, 2):
            raise Kill

    cfg = make_cfg(base, tmp_path)
    with pytest.raises(Kill):
        correct(cfg, on_phase=kill)
    root = Path(cfg.dataset)
    n = len(load_episode_table(root))
    assert n == 4 + (2 if phase == "committed" else 1) * E
    progress = json.loads((Path(cfg.output_dir) / "progress.json").read_text())
    assert not progress["rounds"]["2"].get("appended")
    with pytest.raises(FileExistsError, match="--resume=true"):
        correct(cfg)
    prog = correct(replace(cfg, resume=True))
    eps = load_episode_table(root)
    assert len(eps) == 4 + 2 * E  # nothing lost, nothing duplicated
    assert list(eps["provenance/round"]) == [0] * 4 + [1] * E + [2] * E
    assert prog["rounds"]["2"]["trained"] and prog["rounds"]["2"]["appended"]
    # the run ends where the uninterrupted one did
    ref_cfg = two_rounds[0]
    ref_eps = load_episode_table(Path(ref_cfg.dataset))
    cols = ["length", "provenance/round", "provenance/terrain"]
    assert ref_eps[cols].equals(eps[cols])
    # committed episodes were recognised (not rolled out again); otherwise redone
    assert prog["rounds"]["2"].get("recovered_after_commit", False) == (phase == "committed")
    assert prog["rounds"]["2"]["episodes_after"] == 4 + 2 * E
    # MSTA inference on CPU is reproducible to ~1e-8 only, so compare with a tolerance
    a = WindowDataset(root, ["joint_pos"], T=1, extra_columns=("executed_action",))
    b = WindowDataset(Path(ref_cfg.dataset), ["joint_pos"], T=1,
                      extra_columns=("executed_action",))
    idx = np.arange(len(a))
    np.testing.assert_allclose(a.get_batch(idx)["executed_action"],
                               b.get_batch(idx)["executed_action"], atol=1e-3)


def test_bad_inputs(base, tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing to resume"):
        correct(make_cfg(base, tmp_path, resume=True))
    with pytest.raises(ValueError, match="--policy is required"):
        correct(make_cfg(base, tmp_path, policy=""))
    with pytest.raises(FileNotFoundError, match="no config.json"):
        correct(make_cfg(base, tmp_path, policy=str(tmp_path)))
    assert not (tmp_path / "out").exists()
    with pytest.raises(ValueError, match="beta"):
        make_cfg(base, tmp_path, beta=1.5)
    with pytest.raises(SystemExit, match="unknown teacher type 'nope'"):
        main(["--teacher.type=nope"])

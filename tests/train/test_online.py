"""msta-correct (stage 2): student rollouts labelled by the teacher, appended, retrained."""

from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from msta.collect.record import CollectConfig, collect
from msta.collect.recorder import record_rollouts
from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.data.budget import TimeLimitReached
from msta.data.stats import load_stats
from msta.data.windows import WindowDataset, load_episode_table
from msta.policies.checkpoint import PolicyPath
from msta.policies.factory import make_policy
from msta.policies.msta import MSTAConfig, MSTAPolicy
from msta.policies.teacher.config import TeacherConfig, build_teacher
from msta.policies.weights import weights_revision
from msta.train.correct_config import CorrectConfig, RoundEvalConfig
from msta.train.correct_progress import CorrectProgress
from msta.train.online import main
from msta.train.stage2 import correct

TERRAIN = TerrainConfig(types=("flat", "stairs_up"), num_levels=2, max_init_level=1,
                        border=2.0)
E = 4  # episodes per round
EPISODE_S = 0.3


#: the per-round evaluation of the two-round run: 4 trials of 1 s on two terrains
EVAL = RoundEvalConfig(trials=4, episode_length_s=1.0, terrains="flat,stairs_up", levels="0",
                  mask_ratios=(0.0, 0.5))


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
    defaults = {"policy": PolicyPath(str(base[1])), "dataset": str(root),
                "output_dir": str(tmp_path / "out"), "rounds": 2, "episodes_per_round": E,
                "num_envs": 4, "episode_length_s": EPISODE_S, "env": small_env(),
                "teacher": TeacherConfig(type="gait"), "steps": 3, "batch_size": 8,
                "warmup_steps": 1, "progress": False, "device": "cpu",
                "eval": RoundEvalConfig(enabled=False), "keep_unfinished": False}
    return CorrectConfig(**{**defaults, **kw})


def file_hashes(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted((root / "data").rglob("*.parquet"))}


@pytest.fixture(scope="module")
def two_rounds(base, tmp_path_factory) -> tuple[CorrectConfig, CorrectProgress, dict[str, str]]:
    """An uninterrupted two-round run: (config, progress, teacher data file hashes)."""
    tmp = tmp_path_factory.mktemp("two_rounds")
    cfg = make_cfg(base, tmp, eval=EVAL)
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
    start_rev = weights_revision(MSTAPolicy.from_pretrained(base[1]))
    round1_rev = weights_revision(MSTAPolicy.from_pretrained(out / "round_1"))
    assert round1_rev != start_rev
    for r, rev in ((1, start_rev), (2, round1_rev)):
        tail = eps.iloc[4 + (r - 1) * E: 4 + r * E]
        assert (tail["provenance/source"] == "student").all()
        assert (tail["provenance/round"] == r).all()
        assert (tail["provenance/policy"] == "msta").all()
        assert (tail["provenance/policy_revision"] == rev).all()
        assert set(tail["provenance/terrain"]) <= set(TERRAIN.types)
        assert prog.rounds[r].policy_revision == rev
    assert (eps.iloc[:4]["provenance/source"] == "teacher").all()
    MSTAPolicy.from_pretrained(out / "round_2")
    # the round checkpoints keep the student's stage-1 mask ratio; training.json (and the
    # round record) say which ratio the round retrained at: 0.5, the stage-2 default
    start_ratio = MSTAPolicy.from_pretrained(base[1]).config.mask_ratio
    assert start_ratio > 0.5
    for r in (1, 2):
        assert MSTAPolicy.from_pretrained(out / f"round_{r}").config.mask_ratio == start_ratio
        record = json.loads((out / f"round_{r}" / "training.json").read_text())
        assert record["stage"] == 2 and record["round"] == r and record["mask_ratio"] == 0.5
        assert record["seed"] == cfg.seed + r and prog.rounds[r].train["mask_ratio"] == 0.5
    # per-round evaluation against the teacher on the same trials, both test masks
    assert set(prog.rounds) == {0, 1, 2}
    assert set(prog.rounds[2].eval) == {"0", "0.5"}
    assert prog.teacher_eval["per_terrain"]["average"]["lin_tracking"] > 0
    assert prog.teacher_eval["per_terrain"]["average"]["trials"] == 4
    for r in (0, 1, 2):
        run = prog.rounds[r].eval["0.5"]
        assert run["status"] == "ok" and run["spec"]["mask_ratio"] == 0.5
        assert run["normalized"]["per_terrain"]["average"]["trials"] == 4
        assert prog.rounds[r].eval_config["episode_length_s"] == 1.0
    assert prog.rounds[1].rollout["env_steps_per_s"] > 0
    assert prog.rounds[1].train["train_samples_per_s"] > 0
    # labels: the teacher's action on the recorded (privileged) observation, replayed
    teacher = build_teacher(TeacherConfig(type="gait"))
    teacher.follow_robot = True  # msta-correct's default labelling (--teacher_follows_robot)
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


def test_round_table_model_card_and_msta_eval_agree(two_rounds, tmp_path, capsys):
    """One metric: msta-eval on round 2's checkpoint, over the trials msta-correct evaluated
    it on, reports the figures of msta-correct's round table and of its model card."""
    from msta.eval.evaluate import main as msta_eval
    from msta.eval.report_cells import fmt_cell
    from msta.train.correct_progress import print_table
    from msta.train.push import round_eval

    cfg, prog, _ = two_rounds
    ckpt = Path(cfg.output_dir) / "round_2"
    msta_eval(["--policies", f"teacher,{ckpt}", "--scenarios", "token_removal", "--trials", "4",
               "--episode_length_s", "1", "--terrains", "flat,stairs_up", "--levels", "0", "--seed",
               "0", "--progress", "false", "--output_dir", str(tmp_path / "eval"),
               "--teacher.type", "gait"])  # msta-correct's labeller, its reference here
    metrics = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    runs = {r["condition"]: r for r in metrics["runs"] if r["policy"] == "round_2"}
    card, _ = round_eval(prog.to_json(), 2)
    print_table(prog)
    table = capsys.readouterr().out.split("| 2 |", 1)[1]  # both rows of round 2
    report = (tmp_path / "eval" / "report.md").read_text()
    assert {k: metrics["reference"][k] for k in ("per_terrain", "per_level")} == \
        {k: prog.teacher_eval[k] for k in ("per_terrain", "per_level")}
    for mask, label in (("0", "mask 0%"), ("0.5", "mask 50%")):
        ours, theirs = prog.rounds[2].eval[mask], runs[label]
        assert ours["raw"] == theirs["raw"] and ours["normalized"] == theirs["normalized"]
        norm = theirs["normalized"]["per_terrain"]["average"]
        raw = theirs["raw"]["per_terrain"]["average"]
        assert card[f"lin_tracking_vs_teacher@mask{mask}"] == norm["lin_tracking"]
        assert card[f"survival@mask{mask}"] == raw["survival"]
        assert card[f"total_vs_teacher@mask{mask}"] == norm["total"]
        assert card.get(f"total_vs_teacher_ci95_low@mask{mask}") == norm["ci"]["total"][0]
        assert card["eval_trials"] == raw["trials"] == 4
        for text in (fmt_cell(norm, "lin_tracking"), fmt_cell(norm, "total"),
                     fmt_cell(raw, "survival")):
            assert text in table and text in report, text


def test_beta_one_reproduces_teacher_rollouts(base, tmp_path):
    cfg = make_cfg(base, tmp_path, rounds=1, beta=1.0, teacher_follows_robot=False)
    args = [f"--policy.path={cfg.policy.path}", f"--dataset={cfg.dataset}",
            f"--output_dir={cfg.output_dir}", "--rounds=1", f"--episodes_per_round={E}",
            "--num_envs=4", f"--episode_length_s={EPISODE_S}", "--env.nthread=1",
            "--env.terrain.types=[flat,stairs_up]", "--env.terrain.num_levels=2",
            "--env.terrain.max_init_level=1", "--env.terrain.border=2.0",
            "--env.randomization.pool_size=2", "--teacher.type=gait", "--beta=1.0",
            "--teacher_follows_robot=false",
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
    assert prog.rounds[2].trained and prog.rounds[2].appended
    # the run ends where the uninterrupted one did
    ref_cfg = two_rounds[0]
    ref_eps = load_episode_table(Path(ref_cfg.dataset))
    cols = ["length", "provenance/round", "provenance/terrain"]
    assert ref_eps[cols].equals(eps[cols])
    # committed episodes were recognised (not rolled out again); otherwise redone
    assert prog.rounds[2].recovered_after_commit == (phase == "committed")
    assert prog.rounds[2].episodes_after == 4 + 2 * E
    # MSTA inference on CPU is reproducible to ~1e-8 only, so compare with a tolerance
    a = WindowDataset(root, ["joint_pos"], T=1, extra_columns=("executed_action",))
    b = WindowDataset(Path(ref_cfg.dataset), ["joint_pos"], T=1,
                      extra_columns=("executed_action",))
    idx = np.arange(len(a))
    np.testing.assert_allclose(a.get_batch(idx)["executed_action"],
                               b.get_batch(idx)["executed_action"], atol=1e-3)


def test_max_minutes_stops_at_each_safe_point_and_the_calls_finish_the_run(
        base, two_rounds, tmp_path):
    cfg = make_cfg(base, tmp_path, max_minutes=1e-9)  # passed at once: every call does one unit
    stops: list[str] = []
    for _ in range(20):
        try:
            prog = correct(replace(cfg, resume=bool(stops)))
            break
        except TimeLimitReached as e:
            stops.append(str(e))
    steps = [f"round {r} train: step {s} of 3, checkpoint saved" for r in (1, 2) for s in (1, 2)]
    assert stops == ["round 1: episodes appended", *steps[:2], "round 1: trained",
                     "round 1: done", "round 2: episodes appended", *steps[2:],
                     "round 2: trained"]
    assert prog.rounds[2].trained and prog.rounds[2].evaluated
    cols = ["length", "provenance/round", "provenance/terrain"]
    ref = load_episode_table(Path(two_rounds[0].dataset))[cols]
    assert ref.equals(load_episode_table(Path(cfg.dataset))[cols])  # nothing lost or redone


def test_resume_after_a_kill_during_evaluation_only_evaluates(base, tmp_path):
    def kill(p: str, r: int) -> None:
        if p == "trained":
            raise Kill

    cfg = make_cfg(base, tmp_path, rounds=1, eval=EVAL)
    with pytest.raises(Kill):
        correct(cfg, on_phase=kill)
    before = json.loads((Path(cfg.output_dir) / "progress.json").read_text())
    assert before["rounds"]["0"]["evaluated"] and "eval" not in before["rounds"]["1"]
    prog = correct(replace(cfg, resume=True))
    rec = prog.rounds[1]
    assert rec.evaluated and rec.eval["0"]["status"] == "ok"
    assert rec.rollout == before["rounds"]["1"]["rollout"]     # not rolled out again
    assert prog.rounds[0].to_json() == before["rounds"]["0"]
    assert prog.teacher_eval == before["teacher_eval"]         # same trials, same teacher
    assert len(load_episode_table(Path(cfg.dataset))) == 4 + E


def test_bad_inputs(base, tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing to resume"):
        correct(make_cfg(base, tmp_path, resume=True))
    with pytest.raises(ValueError, match="--policy.path is required"):
        correct(make_cfg(base, tmp_path, policy=PolicyPath("")))
    with pytest.raises(FileNotFoundError, match="no config.json"):
        correct(make_cfg(base, tmp_path, policy=PolicyPath(str(tmp_path))))
    assert not (tmp_path / "out").exists()
    with pytest.raises(ValueError, match="beta"):
        make_cfg(base, tmp_path, beta=1.5)
    with pytest.raises(SystemExit, match="unknown teacher type 'nope'"):
        main(["--teacher.type=nope"])
    with pytest.raises(SystemExit, match="mask_ratios"):
        main(["--eval.mask_ratios=[0.0,1.5]"])
    with pytest.raises(SystemExit, match="unknown terrain 'lava'"):
        main(["--eval.terrains=flat,lava"])


def test_rollouts_start_on_the_levels_of_the_teacher_data(base, tmp_path, capsys):
    """Teacher data from level 0 only: stage-2 rollouts start at level 0 although
    env.terrain allows 0-1 (a student is corrected where stage 1 taught it)."""
    flat = replace(TERRAIN, max_init_level=0)
    root = collect(CollectConfig(teacher=TeacherConfig(type="gait"), episodes=2, num_envs=2,
                                 root=str(tmp_path / "ds"), episode_length_s=EPISODE_S,
                                 progress=False, env=replace(small_env(), terrain=flat)))
    prog = correct(make_cfg(base, tmp_path, rounds=1, episodes_per_round=8))
    assert prog.rollout_max_init_level == 0
    eps = load_episode_table(root)
    assert (eps["provenance/source"] == "student").sum() == 8
    assert (eps["provenance/terrain_level"] == 0).all()
    assert "stage-2 rollouts start at terrain levels 0-0" in capsys.readouterr().out


def test_a_labeller_other_than_the_recording_teacher_is_named(base, tmp_path):
    """The dataset was recorded by the gait teacher: labels from the gait teacher pass
    silently, labels from the RMA teacher are named in a warning (with both revisions)."""
    from msta.train.correct_progress import check_labeller

    same = make_cfg(base, tmp_path)
    assert check_labeller(same, Path(same.dataset)) is None
    other = make_cfg(base, tmp_path, teacher=TeacherConfig(type="rma"))
    warning = check_labeller(other, Path(other.dataset))
    assert warning and "labels come from rma-" in warning and "recorded by gait-" in warning


def test_keep_unfinished_appends_every_simulated_frame_and_resumes(base, tmp_path):
    """The default: each env runs one episode length per round (episodes_per_round /
    num_envs = 1) and every frame is appended, the still-running episodes cut at the end;
    a kill after the commit is recognised with that count."""

    def kill(p: str, r: int) -> None:
        if (p, r) == ("committed", 1):
            raise Kill

    cfg = make_cfg(base, tmp_path, rounds=1, keep_unfinished=True)
    with pytest.raises(Kill):
        correct(cfg, on_phase=kill)
    prog = correct(replace(cfg, resume=True))
    rec = prog.rounds[1]
    assert rec.recovered_after_commit
    eps = load_episode_table(Path(cfg.dataset)).iloc[4:]
    max_steps = replace(small_env(), episode_length_s=EPISODE_S).max_episode_steps
    assert int(eps["length"].sum()) == 4 * max_steps       # every simulated frame
    assert len(eps) == rec.episodes_rolled_out >= E       # falls start new episodes
    assert rec.episodes_after == 4 + len(eps)


def test_rollout_mask_ratios_split_the_envs_and_are_part_of_the_run(base, tmp_path):
    """Half the envs drive at test mask 0.5: the round runs, progress.json records the
    ratios, and a resume with other ratios is refused (they define the data)."""
    from msta.policies.actor import SplitActor
    from msta.train.stage2 import student_actor

    cfg = make_cfg(base, tmp_path, rounds=1, rollout_mask_ratios=(0.0, 0.5))
    prog = correct(cfg)
    assert prog.config["rollout_mask_ratios"] == [0.0, 0.5]
    assert (load_episode_table(Path(cfg.dataset))["provenance/round"] == 1).sum() == E
    with pytest.raises(ValueError, match="rollout_mask_ratios"):
        correct(replace(cfg, resume=True, rounds=2, rollout_mask_ratios=()))
    policy = MSTAPolicy.from_pretrained(base[1])
    split = student_actor(policy, 4, cfg.rollout, cfg.rollout_mask_ratios)
    assert isinstance(split, SplitActor)
    assert [(g.tolist(), a.spec.mask_ratio) for g, a in split.groups] == [([0, 2], 0.0),
                                                                          ([1, 3], 0.5)]
    with pytest.raises(ValueError, match="rollout_mask_ratios: 1.0"):
        make_cfg(base, tmp_path, rollout_mask_ratios=(0.0, 1.0))

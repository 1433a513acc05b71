"""msta-eval end to end: normalization, token removal, determinism, outputs, errors."""

from __future__ import annotations

import json

import matplotlib.image
import numpy as np
import pytest

from msta.data.budget import EXIT_STOPPED
from msta.eval.eval_config import EvalConfig
from msta.eval.evaluate import main
from msta.eval.evaluation import evaluate, load_entries
from msta.eval.evaluator import Evaluator
from msta.eval.metrics import RETURNS
from msta.eval.scenarios import Condition
from msta.policies.input_spec import InputSpec
from msta.policies.teacher.config import TeacherConfig

FAST = {"suite": "quick", "terrains": "flat,smooth_slope", "levels": "0", "progress": False}


def test_teacher_is_exactly_one_and_the_default_pose_far_below(tmp_path):
    cfg = EvalConfig(policies="teacher,teacher:zero", scenarios="token_removal", trials=4,
                     episode_length_s=3.0, output_dir=str(tmp_path),
                     teacher=TeacherConfig(type="gait"), **FAST)
    metrics = evaluate(cfg)
    runs = {(r["policy"], r["condition"]): r for r in metrics["runs"]}
    teacher = runs[("teacher", "mask 0%")]
    for terrain in ("flat", "smooth_slope", "average"):
        cell = teacher["normalized"]["per_terrain"][terrain]
        assert {k: cell[k] for k in RETURNS} == {k: 1.0 for k in RETURNS}
        assert cell["ci"] == {k: [1.0, 1.0] for k in RETURNS}      # paired: no noise
    zero = runs[("zero", "mask 0%")]["normalized"]["per_terrain"]["average"]
    assert zero["lin_tracking"] < 0.5 and zero["total"] < 0.85, zero
    # no input change applies to a teacher: marked n/a with the reason, not skipped
    masked = runs[("teacher", "mask 25%")]
    assert masked["status"] == "n/a" and "teacher" in masked["reason"]
    assert metrics["reference"]["per_terrain"]["flat"]["survival"] > 0
    # every cell says how many trials it holds, and the report header tells the truth
    ref = metrics["reference"]["per_terrain"]
    assert [ref[t]["trials"] for t in ("flat", "smooth_slope", "average")] == [2, 2, 4]
    assert zero["trials"] == 4 and zero["ci"]["lin_tracking"][0] < zero["lin_tracking"]
    report = (tmp_path / "report.md").read_text()
    assert ("4 trials per policy and condition, spread over 2 terrain(s) x 1 level(s): "
            "**2 trial(s) per terrain cell**, 4 in the average") in report
    assert "| *trials per cell* | 2 | 2 | 2 | 2 | 2 | 2 | 4 | 4 | 4 |" in report
    z = runs[("zero", "mask 0%")]["normalized"]["per_terrain"]["flat"]
    assert f"| zero | {z['lin_tracking']:.2f} ±" in report.split("linear-velocity")[1]


def _token_counts(ev: Evaluator, entry, spec: InputSpec) -> int:
    """Tokens the model sees once the history window is full, on real observations.

    The evaluation run itself must succeed with the spec; the count is then taken by
    feeding the same actor class the evaluator uses (StudentActor) 20 consecutive
    observations, so it does not depend on whether a random student falls early."""
    from msta.collect.sim.env import QuadrupedEnv
    from msta.collect.sim.env_config import EnvConfig
    from msta.policies.actor import StudentActor

    rec = ev.condition(entry, Condition("test", repr(spec), 0, spec))
    assert rec["status"] == "ok"
    seen: list[int] = []
    hook = entry.obj.model.blocks[0].register_forward_pre_hook(
        lambda mod, args: seen.append(args[0].shape[1]))
    try:
        env = QuadrupedEnv(EnvConfig(num_envs=2, nthread=1))
        obs = env.reset()
        actor = StudentActor(entry.obj, 2, spec)
        for _ in range(20):
            obs = env.step(actor.act(obs)).obs
    finally:
        hook.remove()
    return seen[-1]


def test_removed_sensors_and_joints_remove_tokens(tiny_ckpt, tmp_path):
    cfg = EvalConfig(policies=str(tiny_ckpt), trials=2, episode_length_s=0.5, output_dir=str(tmp_path),
                     **FAST)
    [entry] = load_entries(cfg)
    ev = Evaluator(cfg, cfg.teacher, progress=False)
    ev.run_reference()
    T = 15
    assert _token_counts(ev, entry, InputSpec()) == 49 * T + 1          # + the state token
    assert _token_counts(ev, entry, InputSpec(drop_sensors=("joint_vel",))) == 37 * T + 1
    assert _token_counts(ev, entry, InputSpec(drop_sensors=("command",))) == 46 * T + 1
    assert _token_counts(ev, entry, InputSpec(dead_joints=(0, 4, 7))) == 43 * T + 1
    assert _token_counts(ev, entry, InputSpec(history=3)) == 49 * 3 + 1
    assert _token_counts(ev, entry, InputSpec(mask_ratio=0.5)) == 49 * T - round(49 * T / 2) + 1


ALL = "token_removal,sensor_removal,dead_joints,history,mask_matrix"


def _cli(out, ckpts, seed=0, scenarios=ALL, extra=()):
    a, b = ckpts
    main(["--policies", f"teacher,{a},{b}", "--suite", "quick", "--output_dir", str(out),
          "--terrains", "flat,stairs_up", "--levels", "0,1", "--trials", "2", "--episode_length_s",
          "0.5", "--seed", str(seed), "--progress", "false", "--scenarios", scenarios,
          "--matrix", f"{a}=0.75:0.5,{b}=0.5:0.5", *extra])
    return (out / "metrics.json").read_bytes()


def test_cli_deterministic_outputs_and_plots(two_ckpts, tmp_path, capsys):
    first = _cli(tmp_path / "a", two_ckpts, extra=("--video", "a75_50:stairs_up",
                                                   "--video_s", "0.3"))
    assert _cli(tmp_path / "b", two_ckpts) == first          # bit for bit
    again = json.loads(_cli(tmp_path / "c", two_ckpts, seed=1, scenarios="token_removal"))
    assert again["runs"][0]["raw"] != json.loads(first)["runs"][0]["raw"]  # the seed matters
    printed = capsys.readouterr().out
    assert "| policy | flat 0% | flat 25% | flat 50% |" in printed
    # the closing line names the plots a run wrote, and says when it wrote none
    assert "and the plots dead_joints.png, history.png, mask_matrix.png, sensor_removal.png in" \
        in printed
    assert printed.rstrip().endswith("(no plots: they draw the sensor_removal, dead_joints, "
                                     "history, dummy_tokens and mask_matrix scenarios)")
    metrics = json.loads(first)
    assert [p["train_masks"] for p in metrics["policies"]] == [None, [0.75, 0.5], [0.5, 0.5]]
    assert all(len(p["revision"]) >= 12 for p in metrics["policies"])
    students = [r for r in metrics["runs"] if r["policy"] != "teacher"]
    assert students and all(r["status"] == "ok" for r in students)
    # masks change what the random-weight student does (the token removal is real)
    by = {(r["policy"], r["condition"]): r for r in students}
    assert by[("a75_50", "mask 0%")]["raw"] != by[("a75_50", "mask 50%")]["raw"]
    report = (tmp_path / "a" / "report.md").read_text()
    assert "## Table I" in report and "| teacher | sensor_removal/-joint_pos | the teacher is the privileged" in report
    for name in ("sensor_removal", "dead_joints", "history", "mask_matrix"):
        img = matplotlib.image.imread(tmp_path / "a" / f"{name}.png")
        assert img.shape[0] > 100 and img.shape[1] > 100 and np.ptp(img) > 0.5, name
    video = next((tmp_path / "a").glob("video_a75_50_stairs_up_L0.mp4"))
    assert video.stat().st_size > 1000


def test_max_minutes_stops_between_rounds_and_the_resumed_metrics_are_identical(
        two_ckpts, tmp_path, capsys):
    one = ("--num_envs", "1")  # 2 trials: each run is 2 rounds of 1 trial
    ref = _cli(tmp_path / "ref", two_ckpts, scenarios="token_removal", extra=one)
    out, calls = tmp_path / "stopped", 0
    while True:  # the limit has passed at once: every call runs one round, keeps it, stops
        calls += 1
        try:
            got = _cli(out, two_ckpts, scenarios="token_removal",
                       extra=(*one, "--max_minutes", "1e-9", "--resume", "true"))
            break
        except SystemExit as e:
            assert e.code == EXIT_STOPPED
            assert not (out / "metrics.json").exists()
            if calls == 1:
                assert [p.name.split(".", 1)[1] for p in (out / "eval_runs").iterdir()] \
                    == ["round0.npz"]
        assert calls < 40
    # reference + teacher row + 2 students x 3 masks, 2 rounds each, one round per call
    assert calls == 2 * len(list((out / "eval_runs").glob("*.npz"))) == 16
    assert got == ref  # the same bytes as the uninterrupted evaluation
    printed = capsys.readouterr().out
    assert "msta-eval: stopped (reference teacher: after round 1 of 2)" in printed
    assert "msta-eval: stopped (before a50_50 | token_removal/mask 0%" in printed
    # without --resume what was kept is deleted first
    with pytest.raises(SystemExit):
        _cli(out, two_ckpts, scenarios="token_removal", extra=(*one, "--max_minutes", "1e-9"))
    assert len(list((out / "eval_runs").glob("*.npz"))) == 1


def test_report_warns_when_a_student_ignores_its_inputs(tiny_ckpt, tmp_path, capsys):
    """A student with zeroed weights acts the same whatever it sees: identical figures for
    test masks 0/25/50 % are flagged; the random-weight student's figures differ: no flag."""
    import torch

    from msta.policies.factory import load_policy

    deaf = load_policy(tiny_ckpt)
    with torch.no_grad():
        for p in deaf.parameters():
            p.zero_()
    deaf_dir = deaf.save_pretrained(tmp_path / "deaf")
    cfg = EvalConfig(policies=f"teacher,{deaf_dir},{tiny_ckpt}", scenarios="token_removal",
                     trials=2, episode_length_s=0.5, output_dir=str(tmp_path / "out"), **FAST)
    metrics = evaluate(cfg)
    line = ("deaf: the student's figures are identical across token_removal conditions "
            "mask 0%, mask 25%, mask 50%: it may ignore its inputs")
    assert line in (tmp_path / "out" / "report.md").read_text()
    printed = capsys.readouterr().out
    assert line in printed and tiny_ckpt.name not in printed.split("warning")[-1]
    from msta.eval.report import identical_warnings
    assert identical_warnings(metrics) == [line]


@pytest.mark.parametrize("args, message", [
    (["--scenarios", "token_removal,bogus"], "unknown scenario 'bogus'"),
    (["--policies", "teacher,/no/such/ckpt"], "'/no/such/ckpt': no such checkpoint directory"),
    (["--policies", "teacher,outptus/ckpt"], "'outptus/ckpt': no such checkpoint directory"),
    (["--terrains", "flat,lava"], "unknown terrain 'lava'"),
    (["--levels", "12"], "level 12 out of range"),
    (["--suite", "huge"], "unknown suite 'huge'"),
    (["--policies", "teacher:nope"], "unknown teacher type 'nope'"),
    (["--device", "tpu9"], "unknown device 'tpu9'; use auto, cpu, cuda or cuda:<index>"),
    (["--scenarios", "history", "--windows", "4,0"], "--windows: '0' is not a window length"),
    (["--scenarios", "history", "--windows", "4,x"], "--windows: 'x' is not a window length"),
    (["--scenarios", "token_removal", "--windows", "4"],
     "--windows needs --scenarios to include history"),
])
def test_clear_errors(args, message, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--output_dir", str(tmp_path), "--progress", "false", *args])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_windows_replace_the_suites_history_sweep(tiny_ckpt, tmp_path):
    cfg = EvalConfig(policies=str(tiny_ckpt), scenarios="history", windows="8,2,4,2", trials=2,
                     episode_length_s=0.3, output_dir=str(tmp_path), **FAST)
    metrics = evaluate(cfg)
    assert [r["condition"] for r in metrics["runs"]] == ["T=2", "T=4", "T=8"]
    assert [r["spec"]["history"] for r in metrics["runs"]] == [2, 4, 8]
    assert metrics["config"]["windows"] == [2, 4, 8]
    assert "windows" not in EvalConfig(policies=str(tiny_ckpt), **FAST).resolved()


def test_eval_settings_are_restored_and_cuda_only_warns():
    """Students on CUDA: deterministic algorithms warn where an op has none instead of
    failing (cuBLAS), and the caller's settings come back afterwards."""
    import torch

    from msta.eval.trial_env import torch_eval_settings

    def state():
        return (torch.are_deterministic_algorithms_enabled(),
                torch.is_deterministic_algorithms_warn_only_enabled(), torch.get_num_threads(),
                torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32)

    before = state()
    torch.backends.cudnn.allow_tf32 = True  # torch's default: TF32 convolutions on CUDA
    try:
        with torch_eval_settings(1, cuda=True):
            assert state() == (True, True, 1, False, False)  # full fp32, warn where no
        with torch_eval_settings(1):                           # deterministic op exists
            assert state()[:2] == (True, False) and state()[4]
        assert state()[4]
    finally:
        torch.backends.cudnn.allow_tf32 = before[4]
    assert state() == before


@pytest.mark.parametrize("name, message", [
    ("tpu9", "unknown device 'tpu9'"), ("meta", "unknown device 'meta'"),
    ("mps", "unknown device 'mps'"), ("cuda:99", "cuda:99"),
])
def test_select_device_accepts_only_the_devices_msta_runs_on(name, message):
    from msta.policies.factory import select_device

    assert select_device("cpu").type == "cpu"
    assert select_device("auto").type in ("cpu", "cuda")
    with pytest.raises(ValueError, match=message):
        select_device(name)

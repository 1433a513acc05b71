"""``make demo`` / ``msta-demo``: the whole msta pipeline on built-in defaults, CPU-sized.

  1. the teacher (default: the shipped PPO-trained RMA MLP, rma_ppo) walks every terrain
     type (summary table + image strip);
  2. msta-collect records a teacher dataset (LeRobot v3.0): 288 episodes of 10 s with noise
     on the executed actions (DART: states off the teacher's path, each labelled with the
     teacher's clean action; recording costs seconds, a student's rollouts minutes);
  3. a local Hugging Face-compatible hub starts and the dataset is pushed (tag v3.0);
  4. msta-train: stage 1 of the MSTA student (cpu preset at T = 4, mask ratio 0.75, the
     paper's stage-1 ratio) on the hub dataset; --push_to pushes the final checkpoint with
     tag stage1 and a model card;
  5. msta-correct: seven DAgger rounds (the student drives alone, half of the robots with
     half of its input tokens removed as in the test at mask 50 %, the teacher labels every
     step, every simulated frame is appended, the student is retrained on everything at
     mask ratio 0.5, the paper's stage-2 ratio); --push_to pushes each round's checkpoint
     with tag stage2-r<r>;
  6. the last round (or, with --select_trials, the best on msta-correct's own round
     evaluation, seed 1) is pulled back by tag and evaluated with msta-eval (test masks
     0 / 25 / 50 %, every paper terrain at levels 0-2, 20 trials per terrain) against the
     teacher (table printed, plots saved);
  7. a one-line verdict: does the student walk like its teacher (normalized linear-velocity
     tracking >= 0.80 at test mask 0 and >= 0.75 at 50 %, survival >= 0.90)?

Why these defaults, and the verdicts of earlier recipes: docs/results/2026-12-04-demo-history.md.

Everything goes under ``--output_dir`` (default ``outputs/demo``); a rerun starts afresh
there; a folder holding files the demo did not write is refused (msta.data.output_dirs).
"""

from __future__ import annotations

import contextlib
import json
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from msta.collect.record import CollectConfig, collect
from msta.collect.sim.env_config import EnvConfig, load_sim_robot
from msta.collect.sim.terrain import TerrainConfig
from msta.collect.simulate import SimRunConfig, simulate
from msta.data import sensors
from msta.data.checks import check_at_least
from msta.data.cli import parse_config
from msta.data.hub_pull import pull
from msta.data.hub_push import push_dataset
from msta.data.hub_server.app import ServerConfig
from msta.data.hub_server.server import HubServer
from msta.data.output_dirs import command_output_dir
from msta.eval.eval_config import EvalConfig
from msta.eval.scenarios import split_csv
from msta.policies.checkpoint import PolicyPath
from msta.policies.msta import MSTAConfig
from msta.policies.teacher.config import TeacherConfig
from msta.train.config import STAGE2_MASK_RATIO, STAGE2_ROLLOUT_MASK_RATIOS
from msta.train.correct_config import CorrectConfig, RoundEvalConfig
from msta.train.train_config import TrainConfig

HUB_USER, HUB_SECRET = "demo", "demo-secret-token"
#: What the demo writes at the top of its --output_dir (a run from before the output marker),
#: and the names of those only the demo writes.
OUTPUTS = frozenset({"teacher", "datasets", "hub", "hub_cache", "pulled", "stage1", "stage2",
                     "eval", "verdict.txt"})
OUTPUTS_SIGN = frozenset({"hub", "hub_cache", "pulled", "verdict.txt"})


def easy_terrain_dataset(root: str | Path, episodes: int, episode_length_s: float,
                         repo_id: str, teacher: TeacherConfig | None = None,
                         action_noise: float = 0.0, extra_sensors: str = "",
                         robot: str = "a1") -> Path:
    """The demo's teacher dataset: a teacher (default: msta's default teacher,
    :class:`~msta.policies.teacher.config.TeacherConfig`'s) on terrain levels 0-2, seed 0,
    up to 64 robots at once (``make demo``, ``msta-repro``, ``make device-check``,
    ``make bench-learn`` and the learning tests share it).

    Args:
        root: dataset root (extended when it already holds fewer episodes).
        episodes: episodes to record.
        episode_length_s: episode time limit (s).
        repo_id: the dataset's ``repo_id``.
        teacher: the recording teacher (None: ``TeacherConfig()``).
        action_noise: ``CollectConfig.action_noise`` (DART).
        extra_sensors: ``CollectConfig.extra_sensors`` (e.g. ``"height_map"``).
        robot: the simulated robot (``EnvConfig.robot``).
    """
    return collect(CollectConfig(
        teacher=teacher or TeacherConfig(), episodes=episodes, num_envs=min(episodes, 64),
        repo_id=repo_id, root=str(root), episode_length_s=episode_length_s, seed=0,
        env=EnvConfig(robot=robot, terrain=TerrainConfig(max_init_level=2)),
        action_noise=action_noise,
        extra_sensors=extra_sensors, progress=False))


def robot_name(robot: str) -> str:
    """The name ``--robot`` gives the demo's datasets and models (``a1_teacher``,
    ``msta_a1``): the spec's ``name``."""
    return load_sim_robot(robot, "robot").name


def step_teacher(out: Path, seconds: float, envs_per_type: int, teacher: TeacherConfig,
                 robot: str) -> None:
    # Curriculum on: robots start at levels 0-2 (off would spread them over all 10 levels).
    terrain = TerrainConfig(curriculum=True, max_init_level=2)
    cfg = SimRunConfig(robot=robot,
                       env=EnvConfig(num_envs=envs_per_type * len(terrain.types), seed=0,
                                     terrain=terrain, robot=robot),
                       teacher=teacher, seconds=seconds,
                       output_dir=str(out / "teacher"), progress=False)
    print(f"\n== 1. the {teacher.type} teacher on every terrain type ({envs_per_type} robots per type, "
          f"levels 0-2, {seconds:.0f} s) ==")
    simulate(cfg)


def step_collect(out: Path, episodes: int, seconds: float, teacher: TeacherConfig,
                 noise: float, robot: str, extra: str = "") -> Path:
    print(f"\n== 2. msta-collect: {episodes} {teacher.type} teacher episodes of up to "
          f"{seconds:.0f} s" + (f", noise of std {noise:g} on its executed actions (DART)"
                                if noise else "") + " ==")
    name = robot_name(robot)
    return easy_terrain_dataset(out / "datasets" / f"{name}_teacher", episodes, seconds,
                                f"demo/{name}_teacher", teacher, action_noise=noise, robot=robot,
                                extra_sensors=extra)


def step_train(out: Path, dataset: str, steps: int, threads: int, history: int,
               mask: float = MSTAConfig.mask_ratio, model: dict[str, Any] | None = None,
               robot: str = "a1", **loop: float) -> Path:
    """Stage 1; ``model``: fields of the student's config over the ``cpu`` preset."""
    model = model or {}
    preset = MSTAConfig.PRESETS["cpu"]
    changed = "".join(f", {k} {v}" for k, v in model.items()
                      if v != preset.get(k, getattr(MSTAConfig, k)))  # what the preset lacks
    print(f"\n== 4. msta-train: stage 1, MSTA cpu preset at T = {history}, {steps} steps, mask "
          f"ratio {mask:g}{changed} ==")
    from msta.train.stage1 import train  # lazy: torch after parsing (--help at once)

    return train(TrainConfig(
        dataset=dataset, policy=MSTAConfig.from_preset(
            "cpu", history=history, mask_ratio=mask, **model),
        output_dir=str(out / "stage1"),
        push_to=f"{HUB_USER}/msta_{robot_name(robot)}", num_threads=threads,
        steps=steps, batch_size=64, warmup_steps=min(100, steps // 5),
        eval_every=max(steps // 2, 1), save_every=steps, progress=False, **loop))


def start_hub(out: Path):
    server = HubServer(ServerConfig(root=str(out / "hub"), host="127.0.0.1", port=0,
                                    tokens=[f"{HUB_USER}:{HUB_SECRET}"]))
    server.start()
    os.environ["HF_ENDPOINT"] = server.url
    os.environ["HF_TOKEN"] = HUB_SECRET
    os.environ["MSTA_HUB_CACHE"] = str(out / "hub_cache")  # the pulled dataset stays in --output_dir
    return server


def step_push(dataset: Path) -> str:
    print("\n== 3. local hub: push the dataset ==")
    sha = push_dataset(dataset, f"{HUB_USER}/{dataset.name}")
    print(f"dataset  {HUB_USER}/{dataset.name}  commit {sha[:12]} (tag v3.0)")
    return f"datasets/{HUB_USER}/{dataset.name}@{sha}"


#: Rounds are compared on msta-eval trials with this seed (the final test uses seed 0).
SELECT_SEED = 1


def round_scores(progress: dict) -> dict[int, float]:
    """Round -> mean over the evaluated test masks of (normalized linear tracking +
    survival), from msta-correct's per-round evaluation in progress.json."""
    scores: dict[int, float] = {}
    for r, entry in progress.get("rounds", {}).items():
        runs = [run for run in (entry.get("eval") or {}).values() if run.get("status") == "ok"]
        if not runs:
            continue
        vals = [(run["normalized"]["per_terrain"]["average"]["lin_tracking"] or 0.0)
                + run["raw"]["per_terrain"]["average"]["survival"] for run in runs]
        scores[int(r)] = sum(vals) / len(vals)
    return scores


def step_correct(out: Path, stage1: Path, dataset: str, rounds: int, steps: int,
                 episodes: int, mask: float, threads: int, select_trials: int,
                 select_s: float, teacher: TeacherConfig,
                 rollout_masks: tuple[float, ...] = (), robot: str = "a1",
                 type_weights: tuple[float, ...] = (), **loop: float) -> int:
    """The stage-2 rounds; returns the round to evaluate (0 = the stage-1 checkpoint): the
    best on the selection trials (DAgger promises a good policy among its iterates, not
    that the last is best). ``select_trials=0``: no round evaluation (it costs about as
    much as a round's rollouts), the last round is evaluated."""

    print(f"\n== 5. msta-correct: {rounds} stage-2 round(s) ({episodes} episodes each: the "
          "student drives alone (DAgger beta 0) at test-time mask "
          f"{' / '.join(f'{m:g}' for m in rollout_masks) or '0'} over its robots, the teacher "
          "labels every step; retrain "
          f"{steps} steps at lr 1e-3, mask ratio {mask:g}) ==")
    cfg = CorrectConfig(policy=PolicyPath(str(stage1)), dataset=dataset, output_dir=str(out / "stage2"),
                        push_to=f"{HUB_USER}/msta_{robot_name(robot)}", num_threads=threads,
                        env=EnvConfig(robot=robot, type_weights=type_weights),
                        rounds=rounds, episodes_per_round=episodes, num_envs=min(episodes, 32),
                        episode_length_s=10.0, steps=steps, batch_size=64, lr=1e-3, beta=0.0,
                        mask_ratio=mask, teacher=teacher, rollout_mask_ratios=rollout_masks,
                        warmup_steps=min(20, steps // 5), eval_every=steps, save_every=steps,
                        **loop,
                        eval=RoundEvalConfig(enabled=select_trials > 0, trials=max(select_trials, 1),
                                        levels="0,1,2",
                                        episode_length_s=select_s, seed=SELECT_SEED, num_threads=threads),
                        progress=False)
    from msta.train.stage2 import correct  # lazy: torch after parsing (--help at once)

    correct(cfg)
    if not select_trials:
        print(f"no round selection (--select_trials=0): evaluating the last round, {rounds}")
        return rounds
    scores = round_scores(json.loads((out / "stage2" / "progress.json").read_text()))
    best = max(scores, key=lambda r: (scores[r], r)) if scores else rounds
    print("selection (msta-correct's round evaluation: {} trials of {:g} s, seed {}; score = "
          "linear tracking vs teacher + survival, averaged over test masks 0 and 50 %): {}; "
          "evaluating round {}".format(
              select_trials, select_s, SELECT_SEED,
              ", ".join(f"round {r} {v:.2f}" for r, v in sorted(scores.items())), best))
    return best


def step_eval(out: Path, best: int, trials: int, episode_length_s: float, threads: int,
              teacher: TeacherConfig, robot: str = "a1") -> dict:
    tag = f"stage2-r{best}" if best else "stage1"
    print(f"\n== 6. pull the {tag} checkpoint by tag and evaluate it (msta-eval: test masks "
          f"0 / 25 / 50 %, {trials} trials of {episode_length_s:g} s over the five terrains at levels "
          "0-2) ==")
    pulled = pull(f"{HUB_USER}/msta_{robot_name(robot)}@{tag}", out / "pulled" / tag)
    print(f"pulled to {pulled}")
    from msta.eval.evaluation import evaluate  # lazy: torch after parsing (--help at once)

    metrics = evaluate(EvalConfig(policies=f"teacher,{pulled}", suite="quick",
                                  scenarios="token_removal", output_dir=str(out / "eval"),
                                  trials=trials, levels="0,1,2", episode_length_s=episode_length_s,
                                  num_threads=threads, progress=False, teacher=teacher,
                                  robot=robot))
    report = out / "eval" / "report.md"
    if report.exists():
        print(report.read_text())
    return metrics


#: The walking-student bar of the verdict (normalized to the teacher on the same trials).
WALKS = {"lin_mask0": 0.80, "lin_mask50": 0.75, "survival": 0.90}


def verdict(metrics: dict) -> tuple[bool, str]:
    """(walks?, one line) from msta-eval's metrics: the student's terrain-averaged
    normalized linear-velocity tracking at test masks 0 and 50 % and its survival."""
    got: dict[float, tuple[float, list | None, float, int]] = {}
    for run in metrics["runs"]:
        if run["policy"] == "teacher" or run.get("status") != "ok":
            continue
        if run["scenario"] != "token_removal":
            continue
        avg_n = run["normalized"]["per_terrain"]["average"]
        avg_r = run["raw"]["per_terrain"]["average"]
        got[float(run["spec"]["mask_ratio"])] = (
            avg_n["lin_tracking"], avg_n["ci"]["lin_tracking"], avg_r["survival"],
            avg_r["trials"])
    if 0.0 not in got or 0.5 not in got:
        return False, "VERDICT: no student figures at test masks 0 and 50 % (evaluation failed)"
    lin0, ci0, surv0, n = got[0.0]
    lin50, ci50, surv50, _ = got[0.5]
    walks = (lin0 is not None and lin50 is not None and lin0 >= WALKS["lin_mask0"]
             and lin50 >= WALKS["lin_mask50"] and min(surv0, surv50) >= WALKS["survival"])

    def fig(v: float | None, ci: list | None) -> str:
        if v is None:
            return "n/a"
        return f"{v:.2f}" + (f" [{ci[0]:.2f}, {ci[1]:.2f}]" if ci else "")

    line = (f"VERDICT: the student {'WALKS' if walks else 'does NOT walk yet'} like its teacher: "
            f"linear tracking vs teacher {fig(lin0, ci0)} at test mask 0 and {fig(lin50, ci50)} "
            f"at 50 % (bar {WALKS['lin_mask0']:.2f} / {WALKS['lin_mask50']:.2f}), survival "
            f"{surv0:.2f} / {surv50:.2f} (bar {WALKS['survival']:.2f}); {n} trials per test "
            "mask, 95 % intervals in brackets")
    return walks, line


@contextlib.contextmanager
def timed(name: str) -> Iterator[None]:
    """Print how long the block took (the demo's time budget is per step)."""
    t0 = time.time()
    yield
    print(f"({name} took {(time.time() - t0) / 60:.1f} min)", flush=True)


@dataclass
class DemoConfig:
    """Args:
        output_dir: where everything goes; a rerun empties it and starts afresh (a folder
            holding files the demo did not write is refused, nothing deleted).
        episodes: teacher episodes to record.
        episode_length_s: teacher episode length (s).
        action_noise: std of noise on the recording teacher's executed actions (DART; its
            clean action stays the label).
        history: the student's window T.
        train_steps: stage-1 optimizer steps.
        train_mask_ratio: stage-1 training mask ratio (the paper's 0.75).
        aux_target: a privileged signal the student also learns to predict in both stages
            (``--policy.aux_target`` of msta-train, e.g. ``base_lin_vel``); empty = none.
        attention: the student's ``--policy.attention``: ``full`` (the paper's), ``step``
            (per-step blocks, then readout blocks over every step) or ``axial`` (blocks
            alternating between a step's tokens and a channel's; docs/msta_model.md).
        readout_layers: with ``step`` attention, how many of the student's blocks read out.
        tokens: the student's ``--policy.tokens``: ``sensor`` (the ``cpu`` preset's: one
            token per sensor and step, removal still per reading) or ``scalar`` (the
            paper's, one token per reading; docs/msta_model.md).
        rounds: stage-2 rounds (0: stage 1 only).
        correct_steps: stage-2 retraining steps per round.
        correct_episodes: stage-2 student episodes (10 s) per round.
        correct_mask_ratio: stage-2 training mask ratio (the paper's 0.5).
        sensor_dropout: both stages: probability that a training sample loses one whole
            physical sensor (msta-train's ``--sensor_dropout``); 0 = off.
        unmasked_share: both stages: share of the optimizer steps that train with every
            token instead of the stage's mask (msta-train's ``--unmasked_share``); 0 = off.
        ema_decay: both stages: the result is an exponential moving average of the weights
            with this decay per step (msta-train's ``--ema_decay``); 0 = off.
        rollout_mask_ratios: test-time mask ratios the stage-2 student drives at, spread
            over the round's environments (msta-correct's option; the default: half of
            them with half of the tokens removed, so the rounds also hold the states the
            test at mask 50 % reaches); empty = all at 0.
        correct_type_weights: the stage-2 rollouts' share of robots per terrain type
            (msta-correct's ``--env.type_weights``, one weight per type: flat, smooth slope,
            rough slope, stairs up, stairs down, discrete); empty = as the simulator's
            default. Puts the rounds' episodes where the student falls.
        select_trials: trials per test mask on which the rounds are compared (seed 1); 0 = no
            comparison, the last round is evaluated.
        select_episode_length_s: episode length of those trials (s).
        teacher_seconds: step 1: how long each robot walks (s).
        envs_per_type: step 1: robots per terrain type.
        eval_trials: msta-eval trials per test mask (spread over 5 terrains x levels 0-2).
        eval_episode_length_s: msta-eval episode length (s).
        num_threads: torch threads for training and evaluation.
        extra_inputs: comma-separated sensors the robot offers beyond the paper's inputs,
            recorded and read by the student besides them (the Go1's ``joint_torque,base_accel``;
            docs/robots.md); empty: the paper's inputs the robot offers.
        robot: the simulated robot, a shipped robot's name (``a1``, ``go1``) or a spec
            file's path (docs/robots.md); names the datasets and models
            (``<robot>_teacher``, ``msta_<robot>``). Another robot than the A1 needs a teacher
            of its own (the shipped ``rma_ppo`` was trained on the A1): the Go1 takes its
            shipped ``go1_ppo`` by default; a robot of your own, ``--teacher.path`` or
            ``--teacher.type=gait``.
        teacher: the teacher that records, labels the stage-2 rounds and is the evaluation's
            reference. Default: the shipped PPO-trained RMA MLP
            (policies/teacher/checkpoints/rma_ppo; memoryless, so its labels on the
            student's states are consistent and the rounds lift the student; docs/teachers.md).
            ``--teacher.type=rma --teacher.path=policies/teacher/checkpoints/rma_dart``: the
            shipped warm start;
            ``--teacher.type=gait``: the gait controller, whose rounds do not lift an MSTA
            student.
    """

    output_dir: str = "outputs/demo"
    episodes: int = 288
    episode_length_s: float = 10.0
    action_noise: float = 0.5
    history: int = 4
    train_steps: int = 4000
    train_mask_ratio: float = MSTAConfig.mask_ratio
    aux_target: str = ""
    attention: str = "full"
    readout_layers: int = 1
    tokens: str = MSTAConfig.PRESETS["cpu"]["tokens"]
    rounds: int = 7
    correct_steps: int = 1300
    correct_episodes: int = 32
    correct_mask_ratio: float = STAGE2_MASK_RATIO
    rollout_mask_ratios: tuple[float, ...] = STAGE2_ROLLOUT_MASK_RATIOS
    correct_type_weights: tuple[float, ...] = ()
    sensor_dropout: float = 0.0
    unmasked_share: float = 0.0
    ema_decay: float = 0.0
    select_trials: int = 0
    select_episode_length_s: float = 5.0
    teacher_seconds: float = 8.0
    envs_per_type: int = 8
    eval_trials: int = 100
    eval_episode_length_s: float = 5.0
    num_threads: int = 2
    extra_inputs: str = ""
    robot: str = "a1"
    teacher: TeacherConfig = field(default_factory=TeacherConfig)

    def __post_init__(self) -> None:
        check_at_least(self, 1, "episodes", "history", "train_steps", "correct_steps", "correct_episodes",
                       "envs_per_type", "eval_trials", "num_threads")
        if self.select_trials < 0:
            raise ValueError(f"select_trials={self.select_trials} must be >= 0 (0: no selection)")
        MSTAConfig.from_preset("cpu", **self.model())  # a bad one fails here, in one line
        for name in ("episode_length_s", "select_episode_length_s", "teacher_seconds",
                     "eval_episode_length_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}={getattr(self, name)} must be > 0")
        if self.action_noise < 0:
            raise ValueError(f"action_noise={self.action_noise} must be >= 0")
        if self.rounds < 0:
            raise ValueError(f"rounds={self.rounds} must be >= 0")
        if not 0.0 <= self.train_mask_ratio < 1.0:
            raise ValueError(f"train_mask_ratio={self.train_mask_ratio} must be in [0, 1)")
        if not 0.0 <= self.sensor_dropout <= 1.0:
            raise ValueError(f"sensor_dropout={self.sensor_dropout} must be in [0, 1]")
        if not 0.0 <= self.unmasked_share <= 1.0:
            raise ValueError(f"unmasked_share={self.unmasked_share} must be in [0, 1]")
        if not 0.0 <= self.ema_decay < 1.0:
            raise ValueError(f"ema_decay={self.ema_decay} must be in [0, 1)")
        if not 0.0 <= self.correct_mask_ratio < 1.0:
            raise ValueError(f"correct_mask_ratio={self.correct_mask_ratio} must be in [0, 1)")
        self.teacher = self.teacher.on_robot(self.robot, "msta-demo")
        try:
            EnvConfig(robot=self.robot, type_weights=self.correct_type_weights)
        except ValueError as e:
            raise ValueError(f"correct_type_weights: {e}") from None

    def model(self) -> dict[str, Any]:
        """The student's config fields this demo sets over the ``cpu`` preset (the inputs only
        with ``extra_inputs``: the paper's the robot offers, then those)."""
        fields = {"aux_target": self.aux_target, "attention": self.attention,
                  "readout_layers": self.readout_layers, "tokens": self.tokens}
        if self.extra_inputs:
            offers = load_sim_robot(self.robot, "robot").sensors
            extra = tuple(split_csv(self.extra_inputs))
            more = sorted(s for s in set(offers) - set(sensors.STUDENT_SENSORS)
                          if sensors.get(s).is_student_input)  # never a privileged signal
            if not set(extra) <= set(more):
                raise ValueError(f"extra_inputs={self.extra_inputs}: the robot {self.robot} "
                                 f"offers {', '.join(more) or 'no input'} beyond the paper's")
            fields["input_sensors"] = tuple(s for s in sensors.STUDENT_SENSORS if s in offers) + extra
        return fields


def main(argv: list[str] | None = None) -> None:
    """Run the msta pipeline demo on built-in defaults (``python -m msta.eval.apps.demo --help``)."""
    cfg = parse_config(DemoConfig, argv, prog="python -m msta.eval.apps.demo")
    # a rerun starts afresh, but only in a folder the demo wrote
    out = command_output_dir(cfg.output_dir, "msta-demo", "msta-demo", clear=True,
                             legacy=OUTPUTS, sign=OUTPUTS_SIGN)
    t0 = time.time()
    with timed("step 1"):
        step_teacher(out, seconds=cfg.teacher_seconds, envs_per_type=cfg.envs_per_type,
                     teacher=cfg.teacher, robot=cfg.robot)
    with timed("step 2"):
        dataset = step_collect(out, cfg.episodes, cfg.episode_length_s, cfg.teacher,
                               cfg.action_noise, cfg.robot, cfg.extra_inputs)
    server = start_hub(out)
    loop = {"sensor_dropout": cfg.sensor_dropout, "unmasked_share": cfg.unmasked_share,
            "ema_decay": cfg.ema_decay}
    try:
        with timed("step 3"):
            hub_dataset = step_push(dataset)
        with timed("step 4"):
            stage1 = step_train(out, hub_dataset, cfg.train_steps, cfg.num_threads,
                                cfg.history, cfg.train_mask_ratio, cfg.model(),
                                robot=cfg.robot, **loop)
        best = 0
        if cfg.rounds:
            with timed("step 5"):
                best = step_correct(out, stage1, hub_dataset, cfg.rounds, cfg.correct_steps,
                                    cfg.correct_episodes, cfg.correct_mask_ratio,
                                    cfg.num_threads, cfg.select_trials,
                                    cfg.select_episode_length_s, cfg.teacher,
                                    cfg.rollout_mask_ratios, robot=cfg.robot,
                                    type_weights=cfg.correct_type_weights, **loop)
        with timed("step 6"):
            metrics = step_eval(out, best, cfg.eval_trials, cfg.eval_episode_length_s,
                                cfg.num_threads, cfg.teacher, cfg.robot)
    finally:
        server.stop()
    _, line = verdict(metrics)
    line += f" (checkpoint {f'stage2-r{best}' if best else 'stage1'})"
    (out / "verdict.txt").write_text(line + "\n")
    print(f"\ndemo finished in {(time.time() - t0) / 60:.1f} min; outputs in {out}/")
    print(line)


if __name__ == "__main__":
    main()

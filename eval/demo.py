"""``make demo`` / ``msta-demo``: the whole msta pipeline on built-in defaults, CPU-sized.

  1. the default teacher walks every terrain type (summary table + image strip);
  2. msta-collect records a small teacher dataset (LeRobot v3.0);
  3. a local Hugging Face-compatible hub starts and the dataset is pushed (tag v3.0);
  4. msta-train: stage 1 of the MSTA student (cpu preset) on the hub dataset; --push_to
     pushes the final checkpoint with tag stage1 and a model card;
  5. msta-correct: one round of stage 2 (the student drives, the teacher labels, the
     episodes are appended, the student is retrained); --push_to pushes the round's
     checkpoint with tag stage2-r1 and its evaluation in the model card;
  6. the stage-2 checkpoint is pulled back by tag and evaluated with msta-eval's quick
     suite against the teacher (table printed, plots saved).

Everything goes under ``--out`` (default ``outputs/demo``); a rerun starts afresh.
"""

from __future__ import annotations

import argparse
import os
import shutil
import time
from pathlib import Path

from collect.sim.env import EnvConfig
from collect.sim.terrain import TerrainConfig

HUB_USER, HUB_SECRET = "demo", "demo-secret-token"


def step_teacher(out: Path, seconds: float, envs_per_type: int) -> None:
    from collect.sim.cli import SimRunConfig, simulate

    # Curriculum on: robots start at levels 0-2 (off would spread them over all 10 levels).
    terrain = TerrainConfig(curriculum=True, max_init_level=2)
    cfg = SimRunConfig(env=EnvConfig(num_envs=envs_per_type * len(terrain.types), seed=0,
                                     terrain=terrain),
                       policy="gait", seconds=seconds, out=str(out / "teacher"), progress=False)
    print(f"\n== 1. the gait teacher on every terrain type ({envs_per_type} robots per type, "
          f"levels 0-2, {seconds:.0f} s) ==")
    simulate(cfg)


def step_collect(out: Path, episodes: int, seconds: float) -> Path:
    from collect.record import CollectConfig, collect
    from policies.teacher.config import TeacherConfig

    print(f"\n== 2. msta-collect: {episodes} teacher episodes of up to {seconds:.0f} s ==")
    return collect(CollectConfig(
        teacher=TeacherConfig(type="gait"), episodes=episodes, num_envs=min(episodes, 64),
        repo_id="demo/a1_teacher", root=str(out / "datasets" / "a1_teacher"),
        episode_length_s=seconds, env=EnvConfig(terrain=TerrainConfig(max_init_level=2)),
        progress=False))


def step_train(out: Path, dataset: str, steps: int) -> Path:
    from policies.msta import MSTAConfig
    from train.offline import TrainConfig, train

    print(f"\n== 4. msta-train: stage 1, MSTA cpu preset, {steps} steps, mask ratio 0.75 ==")
    return train(TrainConfig(
        dataset=dataset, policy=MSTAConfig.from_preset("cpu"), output_dir=str(out / "stage1"),
        push_to=f"{HUB_USER}/msta_a1",
        steps=steps, batch_size=64, warmup_steps=min(50, steps // 5), eval_every=max(steps // 2, 1),
        save_every=steps, progress=False))


def start_hub(out: Path):
    from msta_data.hub_server.server import HubServer, ServerConfig

    server = HubServer(ServerConfig(root=str(out / "hub"), host="127.0.0.1", port=0,
                                    tokens=[f"{HUB_USER}:{HUB_SECRET}"]))
    server.start()
    os.environ["HF_ENDPOINT"] = server.url
    os.environ["HF_TOKEN"] = HUB_SECRET
    os.environ["MSTA_HUB_CACHE"] = str(out / "hub_cache")  # the pulled dataset stays in --out
    return server


def step_push(dataset: Path) -> str:
    from msta_data import hub

    print("\n== 3. local hub: push the dataset ==")
    sha = hub.push_dataset(dataset, f"{HUB_USER}/a1_teacher")
    print(f"dataset  {HUB_USER}/a1_teacher  commit {sha[:12]} (tag v3.0)")
    return f"datasets/{HUB_USER}/a1_teacher@{sha}"


def step_correct(out: Path, stage1: Path, dataset: str, steps: int, episodes: int,
                 eval_steps: int) -> Path:
    from train.online import CorrectConfig, correct

    print(f"\n== 5. msta-correct: one stage-2 round ({episodes} student episodes, "
          f"teacher labels, retrain {steps} steps at mask ratio 0.5) ==")
    cfg = CorrectConfig(policy=str(stage1), dataset=dataset, output_dir=str(out / "stage2"),
                        push_to=f"{HUB_USER}/msta_a1",
                        rounds=1, episodes_per_round=episodes, num_envs=min(episodes, 32),
                        episode_length_s=5.0, steps=steps, batch_size=64,
                        warmup_steps=min(20, steps // 5), eval_every=steps, save_every=steps,
                        progress=False)
    cfg.eval.steps = eval_steps
    correct(cfg)
    return out / "stage2" / "round_1"


def step_eval(out: Path, trials: int, episode_s: float) -> None:
    from eval.evaluate import EvalConfig, evaluate
    from msta_data import hub

    print("\n== 6. pull the stage-2 checkpoint by tag and evaluate it (msta-eval quick) ==")
    pulled = hub.pull(f"{HUB_USER}/msta_a1@stage2-r1", out / "pulled" / "stage2-r1")
    print(f"pulled to {pulled}")
    evaluate(EvalConfig(policies=f"teacher,{pulled}", suite="quick", out=str(out / "eval"),
                        trials=trials, episode_s=episode_s, progress=False))
    report = out / "eval" / "report.md"
    if report.exists():
        print(report.read_text())


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description="Run the msta pipeline demo on built-in defaults.")
    p.add_argument("--out", type=Path, default=Path("outputs/demo"), help="output folder")
    p.add_argument("--episodes", type=int, default=48, help="teacher episodes to record")
    p.add_argument("--episode_s", type=float, default=10.0, help="teacher episode length (s)")
    p.add_argument("--train_steps", type=int, default=800, help="stage-1 optimizer steps")
    p.add_argument("--correct_steps", type=int, default=300, help="stage-2 retrain steps")
    p.add_argument("--correct_episodes", type=int, default=16, help="stage-2 student episodes")
    p.add_argument("--teacher_s", type=float, default=8.0, help="step 1 walk per robot (s)")
    p.add_argument("--envs_per_type", type=int, default=8, help="step 1 robots per terrain")
    p.add_argument("--round_eval_steps", type=int, default=150,
                   help="control steps of the per-round evaluation in stage 2")
    p.add_argument("--eval_trials", type=int, default=0, help="msta-eval trials (0: suite's)")
    p.add_argument("--eval_episode_s", type=float, default=0.0,
                   help="msta-eval episode length (0: suite's)")
    args = p.parse_args(argv)
    os.environ.setdefault("MUJOCO_GL", "egl")
    if args.out.exists():
        shutil.rmtree(args.out)
    t0 = time.time()
    step_teacher(args.out, seconds=args.teacher_s, envs_per_type=args.envs_per_type)
    dataset = step_collect(args.out, args.episodes, args.episode_s)
    server = start_hub(args.out)
    try:
        hub_dataset = step_push(dataset)
        stage1 = step_train(args.out, hub_dataset, args.train_steps)
        step_correct(args.out, stage1, hub_dataset, args.correct_steps, args.correct_episodes,
                     args.round_eval_steps)
        step_eval(args.out, args.eval_trials, args.eval_episode_s)
    finally:
        server.stop()
    print(f"\ndemo finished in {(time.time() - t0) / 60:.1f} min; outputs in {args.out}/")


if __name__ == "__main__":
    main()

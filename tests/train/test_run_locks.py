"""Issue 41 (11): every command that writes a run directory locks it for the whole run
(``msta.data.locking.hold_directory``); a second process on the same ``--output_dir`` fails
at once with one line naming the holder's pid, and changes nothing there."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from msta.data.layout import LOCK_NAME
from msta.data.stats import load_stats
from msta.data.windows import load_episode_table
from msta.eval.apps.compare import main as compare_main
from msta.eval.apps.repro import main as repro_main
from msta.eval.evaluate import main as eval_main
from msta.policies.factory import make_policy
from msta.policies.msta import MSTAConfig
from msta.train.correct_config import PROGRESS
from msta.train.finetune import main as finetune_main
from msta.train.finetune_ppo import main as finetune_ppo_main
from msta.train.offline import main as train_main
from msta.train.online import main as correct_main
from msta.train.teacher.cli import main as train_teacher_main

REPO = Path(__file__).resolve().parents[2]
#: holds the locks of the directories it is given, the way every command takes them
HOLDER = ("import sys, time\nfrom msta.data.locking import lock_directory\n"
          "fds = [lock_directory(d) for d in sys.argv[1:]]\nprint('held', flush=True)\n"
          "time.sleep(300)\n")
#: the simulator of the stage-2 commands, as small as it gets
SIM = ["--env.nthread=1", "--env.terrain.types=[flat]", "--env.terrain.num_levels=1",
       "--env.terrain.border=2.0", "--env.randomization.pool_size=2"]
SMALL_ROUNDS = [*SIM, "--rounds=1", "--episodes_per_round=1", "--num_envs=1",
                "--episode_length_s=0.2", "--keep_unfinished=false", "--teacher.type=gait",
                "--steps=1", "--batch_size=8", "--warmup_steps=0", "--eval.enabled=false",
                "--device=cpu", "--progress=false"]


@pytest.fixture(scope="module")
def student(synthetic_dataset, tmp_path_factory) -> Path:
    """An untrained tiny MSTA student of the synthetic dataset."""
    cfg = MSTAConfig.from_preset("tiny", input_sensors=("command", "joint_pos", "gravity"),
                                 history=5)
    path = tmp_path_factory.mktemp("student") / "student"
    return make_policy(cfg, load_stats(synthetic_dataset)).save_pretrained(path)


def hold(*dirs: Path) -> subprocess.Popen:
    """Another process, holding the locks of ``dirs`` until it is killed."""
    for d in dirs:
        d.mkdir(parents=True, exist_ok=True)
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, *map(str, dirs)], cwd=REPO,
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
    return proc


@pytest.fixture
def holder(tmp_path) -> Iterator[tuple[subprocess.Popen, Path]]:
    out = tmp_path / "out"
    proc = hold(out)
    yield proc, out
    proc.kill()
    proc.wait(timeout=30)


def _commands(ds: Path, student: Path) -> dict[str, tuple[Callable, list[str]]]:
    """Console script -> (entry point, arguments of a small run but for --output_dir)."""
    fast = ["--policy.preset=tiny", "--policy.input_sensors=[command,joint_pos,gravity]",
            "--policy.history=5", "--batch_size=8", "--progress=false", "--device=cpu"]
    rounds = [f"--policy.path={student}", f"--dataset={ds}", *SMALL_ROUNDS]
    return {
        "msta-train": (train_main, [f"--dataset={ds}", *fast, "--steps=1"]),
        "msta-correct": (correct_main, rounds),
        "msta-finetune": (finetune_main, [*rounds, "--sensors=all", "--history=5"]),
        "msta-finetune-ppo": (finetune_ppo_main, [
            f"--policy.path={student}", "--sensors=all", "--history=5", *SIM,
            "--env.num_envs=2", "--ppo.iterations=1", "--ppo.num_steps_per_env=2",
            "--num_threads=1", "--device=cpu"]),
        "msta-train-teacher": (train_teacher_main, [
            "--warmstart.iterations=0", "--ppo.iterations=0", *SIM, "--env.num_envs=2",
            "--num_threads=1"]),
        "msta-eval": (eval_main, [
            "--policies=teacher", "--trials=1", "--episode_length_s=0.2", "--num_envs=1",
            "--terrains=flat", "--levels=0", "--nthread=1", "--progress=false"]),
        "msta-compare": (compare_main, [
            f"--dataset={ds}", "--policies=msta", "--preset=tiny", "--stage1_steps=1",
            "--stage2_rounds=0", "--trials=1", "--eval_episode_length_s=0.2",
            "--batch_size=8", "--progress=false"]),
        "msta-repro": (repro_main, ["--scale=tiny", "--progress=false"]),
    }


COMMANDS = ["msta-train", "msta-correct", "msta-finetune", "msta-finetune-ppo",
            "msta-train-teacher", "msta-eval", "msta-compare", "msta-repro"]


@pytest.mark.parametrize("prog", COMMANDS)
def test_a_run_directory_held_by_another_process_is_refused_at_once(
        prog, holder, synthetic_dataset, student, tmp_path, capsys):
    proc, out = holder
    ds = tmp_path / "ds"
    shutil.copytree(synthetic_dataset, ds)
    main, args = _commands(ds, student)[prog]
    with pytest.raises(SystemExit) as err:
        main([*args, f"--output_dir={out}"])
    code = err.value.code  # the message itself, or 2 with the message on stderr
    assert code not in (0, None)
    message = code if isinstance(code, str) else capsys.readouterr().err.strip()
    assert f"(pid {proc.pid}) holds {out / LOCK_NAME}" in message, message
    assert message.count("\n") == 0 and message.startswith(f"{prog}: error: "), message
    assert [p.name for p in out.iterdir()] == [LOCK_NAME]  # nothing written there
    assert len(load_episode_table(ds)) == 12  # nor appended to the dataset


def test_msta_correct_resumed_twice_retrains_once(synthetic_dataset, student, tmp_path):
    """The audit's case: a second ``msta-correct --resume=true`` (a real process) on a run
    another process holds exits non-zero with one line, and the run is left as it was."""
    ds, out = tmp_path / "ds", tmp_path / "out"
    shutil.copytree(synthetic_dataset, ds)
    args = [f"--policy.path={student}", f"--dataset={ds}", f"--output_dir={out}",
            *SMALL_ROUNDS]
    correct_main(args)  # round 1 done
    progress = (out / PROGRESS).read_bytes()
    episodes = len(load_episode_table(ds))
    first = hold(out)
    try:
        second = subprocess.run(
            [sys.executable, "-m", "msta.train.online", *args, "--resume=true", "--rounds=2"],
            check=False, cwd=REPO, capture_output=True, text=True, timeout=300)
    finally:
        first.kill()
        first.wait(timeout=30)
    assert second.returncode != 0
    err = second.stderr.strip()
    assert err == (f"msta-correct: error: {out}: another msta-correct run (pid {first.pid}) "
                   f"holds {out / LOCK_NAME}; only one at a time"), err
    assert (out / PROGRESS).read_bytes() == progress
    assert len(load_episode_table(ds)) == episodes
    assert "2" not in json.loads(progress)["rounds"]

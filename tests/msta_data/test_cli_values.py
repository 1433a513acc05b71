"""Issue 41 (14): a value no run can use (NaN, infinity, a size no memory holds, a negative
thread count) is refused when the command line is parsed: exit 2, one line naming the
option, never a traceback. The bounds come from one helper, ``msta.data.checks.check_number``."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from msta.collect.record import main as collect_main
from msta.collect.simulate import main as sim_main
from msta.eval.evaluate import main as eval_main
from msta.train.finetune import main as finetune_main
from msta.train.finetune_ppo import main as finetune_ppo_main
from msta.train.offline import main as train_main
from msta.train.online import main as correct_main
from msta.train.teacher.cli import main as train_teacher_main

REPO = Path(__file__).resolve().parents[2]

#: (console script, entry point, the bad option, what the message must name)
CASES = [
    ("msta-collect", collect_main, "--episode_length_s=inf", "episode_length_s=inf"),
    ("msta-collect", collect_main, "--num_envs=100000000", "num_envs=100000000"),
    ("msta-collect", collect_main, "--action_noise=nan", "action_noise=nan"),
    ("msta-collect", collect_main, "--env.nthread=-1", "nthread=-1"),
    ("msta-train", train_main, "--lr=inf", "lr=inf"),
    ("msta-train", train_main, "--weight_decay=nan", "weight_decay=nan"),
    ("msta-train", train_main, "--batch_size=100000000", "batch_size=100000000"),
    ("msta-train", train_main, "--grad_clip=nan", "grad_clip=nan"),
    ("msta-train", train_main, "--policy.init_std=nan", "init_std=nan must be a finite number"),
    ("msta-train", train_main, "--policy.sensor_embed_std=inf", "sensor_embed_std"),
    ("msta-correct", correct_main, "--num_envs=100000000", "num_envs=100000000"),
    ("msta-correct", correct_main, "--episode_length_s=inf", "episode_length_s=inf"),
    ("msta-finetune", finetune_main, "--max_minutes=nan", "max_minutes=nan"),
    ("msta-eval", eval_main, "--nthread=-1", "nthread=-1"),
    ("msta-eval", eval_main, "--num_envs=100000000", "num_envs=100000000"),
    ("msta-eval", eval_main, "--episode_length_s=nan", "episode_length_s=nan"),
    ("msta-train-teacher", train_teacher_main, "--ppo.gamma=nan", "ppo.gamma=nan"),
    ("msta-train-teacher", train_teacher_main, "--warmstart.lr=inf", "lr=inf"),
    ("msta-finetune-ppo", finetune_ppo_main, "--env.episode_length_s=inf", "episode_length_s=inf"),
    # every float of the simulator's nested configs, not only the sizes
    ("msta-collect", collect_main, "--env.commands.resample_s=nan", "env.commands.resample_s=nan"),
    ("msta-collect", collect_main, "--env.rewards.tracking_sigma=inf",
     "env.rewards.tracking_sigma=inf"),
    ("msta-train-teacher", train_teacher_main, "--env.control.kp=inf", "env.control.kp=inf"),
    ("msta-train-teacher", train_teacher_main, "--ppo.num_steps_per_env=100000000",
     "num_steps_per_env=100000000"),
    ("msta-finetune-ppo", finetune_ppo_main, "--ppo.num_steps_per_env=100000000",
     "num_steps_per_env=100000000"),
    ("msta-finetune-ppo", finetune_ppo_main, "--env.noise.scale=nan", "env.noise.scale=nan"),
    # sizes that asked for gigabytes or thousands of processes before anything failed
    ("msta-train", train_main, "--policy.history=100000", "history must be <= 250 steps"),
    ("msta-collect", collect_main, "--workers=100000", "workers=100000 must be an integer in"),
    ("msta-eval", eval_main, "--workers=100000", "workers=100000 must be an integer in"),
    ("msta-collect", collect_main, "--env.noise.scale=1e300", "env.noise.scale=1e+300"),
    ("msta-collect", collect_main, "--seed=99999999999999999999999", "within the 64-bit"),
    ("msta-eval", eval_main, "--max_minutes=nan", "max_minutes=nan must be a finite number"),
    ("msta-sim", sim_main, "--seconds=nan", "seconds=nan must be a finite number"),
]


@pytest.mark.parametrize(("prog", "main", "option", "names"), CASES,
                         ids=[f"{c[0]} {c[2]}" for c in CASES])
def test_unusable_values_are_one_line_errors_at_parse_time(prog, main, option, names, capsys,
                                                           tmp_path):
    with pytest.raises(SystemExit) as e:
        main([option, f"--output_dir={tmp_path / 'out'}"] if "collect" not in prog
             else [option, f"--root={tmp_path / 'out'}"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"{prog}: error: "), err
    assert names in err and "must be" in err and "Traceback" not in err, err
    assert not (tmp_path / "out").exists()  # refused before anything was written


def test_the_real_command_line_says_it_in_one_line():
    """The console script itself (a subprocess): exit 2, one line on stderr, no traceback."""
    proc = subprocess.run([sys.executable, "-m", "msta.train.offline", "--lr=inf", "--dataset=x"],
                          check=False, cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    err = proc.stderr.strip()
    assert err == "msta-train: error: --lr=inf must be a finite number", err


@pytest.mark.parametrize("main,prog", [(eval_main, "msta-eval"), (sim_main, "msta-sim"),
                                       (train_main, "msta-train")])
@pytest.mark.parametrize("kind", ["/dev/null", "file", "fifo"])
def test_an_output_folder_that_is_a_file_is_one_line(main, prog, kind, tmp_path, capsys):
    import os

    path = {"/dev/null": "/dev/null", "file": str(tmp_path / "f"), "fifo": str(tmp_path / "p")}
    (tmp_path / "f").write_text("mine")
    os.mkfifo(tmp_path / "p")
    with pytest.raises(SystemExit) as e:
        main([f"--output_dir={path[kind]}"])
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2 and len(err.splitlines()) == 1
    assert err == (f"{prog}: error: --output_dir={path[kind]} is not a folder (a file, a device "
                   "or a FIFO is there); choose a folder")
    assert (tmp_path / "f").read_text() == "mine"


def test_a_report_of_a_file_that_is_not_a_metrics_json_is_one_line(tmp_path):
    (tmp_path / "bad.json").write_text("not json")
    (tmp_path / "list.json").write_text("[1, 2]")
    for name in ("bad.json", "list.json"):
        proc = subprocess.run([sys.executable, "-m", "msta.eval.report", str(tmp_path / name)],
                              cwd=REPO, capture_output=True, text=True, timeout=120, check=False)
        err = proc.stderr.strip()
        assert proc.returncode == 1 and len(err.splitlines()) == 1, err
        assert err.startswith(f"python -m msta.eval.report: error: {tmp_path / name}: not a "
                              "metrics.json of msta-eval")

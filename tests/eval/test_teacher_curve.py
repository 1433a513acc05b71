"""msta.eval.teacher_curve: a teacher run's snapshots evaluated on fixed tiles, cached."""

from __future__ import annotations

import json
import shutil
import tomllib

import pytest
import torch

import msta.eval.teacher_curve as tc
from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.data.robot import A1
from msta.policies.teacher.config import TeacherConfig
from msta.train.ppo_config import PPOConfig
from msta.train.teacher.config import TrainTeacherConfig, WarmStartConfig
from msta.train.teacher.run import train_teacher


@pytest.fixture(scope="module", autouse=True)
def _restore_torch_threads():
    before = torch.get_num_threads()    # main() and train_teacher set torch's threads
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    env = EnvConfig(num_envs=8, episode_length_s=1.0, nthread=1,
                    terrain=TerrainConfig(types=("flat", "smooth_slope"), num_levels=3,
                                          max_init_level=1))
    train_teacher(TrainTeacherConfig(
        output_dir=str(out), num_threads=1, device="cpu",
        warmstart=WarmStartConfig(iterations=1, steps=20, fit_steps=5),
        ppo=PPOConfig(iterations=4, num_steps_per_env=4, save_interval=2, critic_warmup=2,
                      snapshot_interval=2), env=env), log=lambda s: None)
    return out


def test_every_snapshot_and_both_references_are_evaluated_once(run, tmp_path, monkeypatch):
    argv = [f"--run={run}", "--terrains=flat", "--level=0", "--episodes=2",
            "--envs_per_tile=2", "--episode_length_s=0.4", "--nthread=1",
            f"--image={tmp_path / 'curve.png'}", "--progress=false"]
    calls: list[str] = []
    real = tc.figures_of
    monkeypatch.setattr(tc, "figures_of",
                        lambda teacher, cfg: calls.append(teacher.type) or real(teacher, cfg))
    tc.main(argv)
    assert calls == ["gait", "rma", "rma", "rma"]          # gait, start, iterations 2 and 4
    caches = json.loads((run / "curve_eval.json").read_text())["caches"]
    assert len(caches) == 1 and caches[0]["settings"]["episodes"] == 2
    cache = caches[0]
    assert set(cache["references"]) == {"gait controller", "start"}
    assert set(cache["snapshots"]) == {"2", "4"}
    assert all(0.0 <= v["survival"]["flat"] <= 1.0 and v["lin_err"]["flat"] >= 0.0
               for v in cache["snapshots"].values())
    assert (tmp_path / "curve.png").stat().st_size > 10_000
    # a re-run evaluates nothing already cached ...
    calls.clear()
    tc.main(argv)
    assert calls == []
    # ... but a snapshot whose files changed, and a removed snapshot is dropped
    snap2 = run / "snapshots" / "iter_2"
    shutil.copy(run / "snapshots" / "iter_4" / "model.safetensors", snap2 / "model.safetensors")
    tc.main(argv)
    assert calls == ["rma"]
    shutil.rmtree(snap2)
    tc.main(argv)
    assert calls == ["rma"]
    assert set(json.loads((run / "curve_eval.json").read_text())["caches"][0]["snapshots"]) == {"4"}
    # other settings get a cache of their own; --every keeps one snapshot per multiple + newest
    calls.clear()
    other = [a if not a.startswith("--episodes=") else "--episodes=4" for a in argv]
    tc.main([*other, "--every=8"])
    assert calls == ["gait", "rma", "rma"]                  # gait, start, the newest (4)
    assert len(json.loads((run / "curve_eval.json").read_text())["caches"]) == 2


def test_thin_keeps_the_first_snapshot_at_or_after_each_multiple_and_the_newest():
    found = [(it, None) for it in (100, 201, 301, 390, 401, 460)]
    assert [it for it, _ in tc.thin(found, 200)] == [100, 201, 401, 460]
    assert [it for it, _ in tc.thin(found, 0)] == [it for it, _ in found]


def test_a_directory_without_a_curve_is_a_one_line_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        tc.main([f"--run={tmp_path}"])
    assert e.value.code == 2
    assert "no curve.json" in capsys.readouterr().err


def test_robot_is_the_robot_every_teacher_runs_on(tmp_path):
    """--robot reaches the simulator: a limp robot (kp 0.5) falls where the A1 stands, and
    its figures are cached apart from the A1's (whose cache key is as before)."""
    (tmp_path / "curve.json").write_text("[]")
    data = tomllib.loads(A1.spec_file.read_text()) | {"name": "limp", "mjcf": str(A1.mjcf_path),
                                                     "kp": 0.5}
    limp = tmp_path / "limp.toml"
    limp.write_text("".join(f"{k} = {json.dumps(v)}\n" for k, v in data.items()))
    common = {"run": str(tmp_path), "terrains": "flat", "level": 0, "episodes": 2,
              "envs_per_tile": 2, "episode_length_s": 1.0, "nthread": 1, "image": "",
              "progress": False}
    a1, other = tc.TeacherCurveConfig(**common), tc.TeacherCurveConfig(**common, robot=str(limp))
    zero = TeacherConfig(type="zero")
    standing, limp_falls = tc.figures_of(zero, a1), tc.figures_of(zero, other)
    assert standing["survival"] == {"flat": 1.0}
    assert limp_falls["survival"] == {"flat": 0.0}
    assert standing["lin_err"]["flat"] > 0.1           # it stands while the command moves
    assert "robot" not in tc.settings_key(a1)
    assert tc.settings_key(other) == {**tc.settings_key(a1), "robot": str(limp)}
    with pytest.raises(ValueError, match="robot=b2: unknown robot 'b2'"):
        tc.TeacherCurveConfig(**common, robot="b2")


def test_the_table_shows_the_velocity_error_where_it_was_recorded(tmp_path):
    """A snapshot's cells carry its mean velocity error; an entry cached before the error
    was recorded shows survival alone."""
    (tmp_path / "curve.json").write_text('[{"iteration": 100, "env_steps": 12288}]')
    cache = {"settings": {"terrains": "flat", "level": 2, "episodes": 100},
             "references": {"start": {"survival": {"flat": 0.9}}},
             "snapshots": {"100": {"survival": {"flat": 0.97}, "lin_err": {"flat": 0.214}}}}
    start, snap = tc.table(cache, tmp_path).splitlines()[2:]
    assert start.startswith("| start | - | 0.90 (") and "m/s" not in start
    assert snap.startswith("| iteration 100 | 12,288 | 0.97 (") and snap.endswith(", 0.21 m/s |")


def test_the_best_snapshot_breaks_ties_on_mean_survival_then_velocity_error():
    gait = {"survival": {"a": 0.5, "b": 0.5}}

    def snap(a: float, b: float, err: float | None = None) -> dict:
        return {"survival": {"a": a, "b": b}} | ({"lin_err": {"a": err, "b": err}} if err else {})

    cache = {"references": {"gait controller": gait},
             "snapshots": {"100": snap(0.97, 0.94, 0.25), "200": snap(0.94, 0.97, 0.20),
                           "300": snap(0.94, 0.94, 0.10), "400": snap(0.90, 1.00, 0.05)}}
    assert tc.best_snapshot(cache) == ("200", pytest.approx(0.44))  # 100 and 200 tie twice
    cache["snapshots"]["150"] = snap(0.97, 0.94)                     # no error recorded ...
    assert tc.best_snapshot(cache)[0] == "200"                       # ... loses the tie
    cache["snapshots"]["500"] = snap(0.94, 0.98)
    assert tc.best_snapshot(cache)[0] == "500"                       # higher mean survival
    assert tc.best_snapshot({"references": {}, "snapshots": cache["snapshots"]}) is None

"""The sensor guard (policies/guard.py) on episodes recorded in the real simulator: it
flags a stuck encoder, a 3-std bias and 3-std noise within 10 steps, stays quiet on the
fault-free stream it was calibrated on, latches until reset, flags q and q-dot together,
and round-trips through a checkpoint folder."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from msta_test_helpers import record_gait  # registered by tests/conftest.py

import msta.policies.teacher.gait  # noqa: F401  (registers "gait")
from msta.data.stats import load_stats
from msta.policies.guard import INPUT_SENSORS, OFFSET, GuardConfig, SensorGuard
from msta.policies.guard_file import load_guard, save_guard
from msta.train.guard_data import load_episodes
from msta.train.guard_fit import fit_guard

pytestmark = pytest.mark.usefixtures("one_thread")
ONSET = 100


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """Six 4-second gait-teacher episodes on flat ground."""
    return record_gait(tmp_path_factory.mktemp("guard_data") / "dataset", 6, 4.0)


@pytest.fixture(scope="module")
def fitted(recorded) -> tuple[SensorGuard, dict]:
    return fit_guard(recorded), load_episodes(recorded)


def std_of(root: Path, sensor: str) -> np.ndarray:
    return np.asarray(load_stats(root)[f"observation.{sensor}"]["std"])


def inject(data: dict, kind: str, sensor: str, ch: int, size: float, seed: int = 0) -> dict:
    """A copy of the episodes with one channel faulty from ``ONSET`` on."""
    out = {s: data[s].copy() for s in INPUT_SENSORS}
    x = out[sensor][:, ONSET:, ch]
    if kind == "stuck":
        x[:] = x[:, :1]
    elif kind == "bias":
        x += size
    else:  # noise
        x += size * np.random.default_rng(seed).standard_normal(x.shape)
    return out


def run(guard: SensorGuard, data: dict, steps: int | None = None) -> np.ndarray:
    """Latched flags (E, T, 34) of a fresh copy of ``guard`` streamed over ``data``."""
    e, t = data["joint_pos"].shape[:2]
    g = SensorGuard(guard.cfg, guard.stats, guard.sensors, e, guard.dt)
    flags = []
    for i in range(steps or t):
        g.update({s: data[s][:, i] for s in INPUT_SENSORS})
        flags.append(g.flags.copy())
    return np.stack(flags, 1)


def test_no_flag_on_the_fault_free_stream_it_was_calibrated_on(fitted):
    guard, data = fitted
    flags = run(guard, data)
    valid = np.arange(flags.shape[1])[None] < data["length"][:, None]
    assert flags[valid].sum() <= 1e-4 * valid.sum() * flags.shape[2]


@pytest.mark.parametrize("kind,sensor,ch,std_mult", [
    ("stuck", "encoder", 2, 0.0), ("bias", "joint_pos", 4, 3.0), ("bias", "joint_vel", 7, 3.0),
    ("noise", "joint_pos", 1, 3.0), ("noise", "joint_vel", 10, 3.0)])
def test_flags_the_fault_within_10_steps(fitted, recorded, kind, sensor, ch, std_mult):
    guard, data = fitted
    if sensor == "encoder":  # q and q-dot stuck together
        faulty = inject(inject(data, kind, "joint_pos", ch, 0.0), kind, "joint_vel", ch, 0.0)
        sensor = "joint_pos"
    else:
        faulty = inject(data, kind, sensor, ch, std_mult * std_of(recorded, sensor)[ch])
    flags = run(guard, faulty, ONSET + 10)
    col = OFFSET[sensor] + ch
    assert not flags[:, ONSET - 1].any()  # nothing before the onset
    assert flags[:, -1, col].all()  # every episode flagged by the 10th faulty step


def test_flags_latch_until_reset_and_flag_q_with_q_dot(fitted, recorded):
    guard, data = fitted
    faulty = inject(data, "bias", "joint_vel", 3, 3 * std_of(recorded, "joint_vel")[3])
    e = data["joint_pos"].shape[0]
    g = SensorGuard(guard.cfg, guard.stats, guard.sensors, e, guard.dt)
    for i in range(ONSET + 10):
        out = g.update({s: faulty[s][:, i] for s in INPUT_SENSORS})
    assert out["joint_vel"][:, 3].all() and out["joint_pos"][:, 3].all()  # the encoder
    for i in range(ONSET + 10, ONSET + 30):  # the fault is gone: the flags stay
        out = g.update({s: data[s][:, i] for s in INPUT_SENSORS})
    assert out["joint_vel"][:, 3].all()
    g.reset([0])
    out = g.flagged()
    assert not out["joint_vel"][0].any() and out["joint_vel"][1:, 3].all()


def test_save_and_load_give_the_same_flags(fitted, recorded, tmp_path):
    guard, data = fitted
    assert load_guard(tmp_path) is None
    save_guard(guard, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["guard.json", "guard.safetensors"]
    back = load_guard(tmp_path)
    faulty = inject(data, "noise", "joint_pos", 5, 3 * std_of(recorded, "joint_pos")[5])
    a, b = run(guard, faulty), run(back, faulty)
    assert a[:, -1].any() and (a == b).all()


def test_the_guard_judges_only_after_its_warmup(fitted, recorded):
    """Every statistic is 0 for the first ``warmup`` steps, even with a channel biased
    from the first step; a fault present from the start is flagged once it ends."""
    guard, data = fitted
    biased = {s: data[s].copy() for s in INPUT_SENSORS}
    biased["joint_pos"][:, :, 4] += 3 * std_of(recorded, "joint_pos")[4]
    g = SensorGuard(guard.cfg, guard.stats, guard.sensors, len(data["length"]), guard.dt)
    w = guard.cfg.warmup
    stats = np.stack([g.statistics({s: biased[s][:, t] for s in INPUT_SENSORS})
                      for t in range(w + 10)], 1)
    assert w == 50 and not stats[:, :w].any() and stats[:, w:].any()
    flags = run(guard, biased, w + 10)
    assert flags[:, -1, OFFSET["joint_pos"] + 4].all()


def test_only_the_guarded_sensors_are_reported(fitted):
    guard, data = fitted
    g = SensorGuard(guard.cfg, guard.stats, ("joint_pos",), 6, guard.dt)
    assert list(g.update({s: data[s][:, 0] for s in INPUT_SENSORS})) == ["joint_pos"]


@pytest.mark.parametrize("make,match", [
    (lambda s: GuardConfig(window=0), r"guard window must be an integer in \[1, 1000\], got 0"),
    (lambda s: GuardConfig(margin=-1.0), r"guard margin must be a number in \(0, 1e\+06\]"),
    (lambda s: SensorGuard(GuardConfig(), s, ("command",)), "guard sensors must be"),
    (lambda s: SensorGuard(GuardConfig(), s, num_envs=0), "num_envs >= 1"),
    (lambda s: SensorGuard(GuardConfig(), {**s, "threshold": s["threshold"][:3]}),
     r"guard array 'threshold' must be not NaN and >= 0 with shape \(\d+,\), got shape \(3,\)"),
])
def test_bad_values_are_one_line_errors(fitted, make, match):
    with pytest.raises(ValueError, match=match) as err:
        make(fitted[0].stats)
    assert "\n" not in str(err.value)


def test_a_missing_input_is_named(fitted):
    guard, data = fitted
    obs = {s: data[s][:, 0] for s in INPUT_SENSORS if s != "gravity"}
    with pytest.raises(KeyError, match="gravity"):
        SensorGuard(guard.cfg, guard.stats, num_envs=6).update(obs)


def test_a_single_spike_trips_the_two_sided_statistic_one_step_late(fitted, recorded):
    guard, data = fitted
    ch = 5
    faulty = {s: data[s].copy() for s in INPUT_SENSORS}
    faulty["joint_vel"][:, ONSET, ch] += 5 * std_of(recorded, "joint_vel")[ch]  # one step
    e = data["joint_pos"].shape[0]
    g = SensorGuard(guard.cfg, guard.stats, guard.sensors, e, guard.dt)
    for i in range(ONSET + 1):
        g.update({s: faulty[s][:, i] for s in INPUT_SENSORS})
    stat = g.statistics({s: faulty[s][:, ONSET + 1] for s in INPUT_SENSORS})
    col = g.names.index(f"z2:{OFFSET['joint_vel'] + ch}")
    assert (stat[:, col] > g.stats["threshold"][col]).all()


def test_explaining_away_keeps_a_biased_channel_from_flagging_others(recorded):
    # ridge 30: on these 1,200 steps a looser fit leans on single channels so hard that
    # their normal residuals, taken out, leave others flagged (the demo's 200,000 steps
    # fit fine at ridge 1)
    data = load_episodes(recorded)
    biased = inject(data, "bias", "joint_pos", 4, 3 * std_of(recorded, "joint_pos")[4])
    others = np.ones(34, bool)
    others[[OFFSET["joint_pos"] + 4, OFFSET["joint_vel"] + 4]] = False
    collateral = {}
    for explain in (False, True):
        guard = fit_guard(recorded, cfg=GuardConfig(explain=explain, ridge=30.0))
        flags = run(guard, biased, ONSET + 10)
        assert not flags[:, ONSET - 1].any() and flags[:, -1, OFFSET["joint_pos"] + 4].all()
        collateral[explain] = flags[:, -1, others].any(1).mean()
    assert collateral[False] > 0.5 and collateral[True] == 0


def test_a_guard_saved_before_the_two_sided_statistics_loads_as_it_was(recorded, tmp_path):
    import json

    from safetensors.numpy import save_file

    old = fit_guard(recorded, cfg=GuardConfig(two_sided=False, explain=False,
                                              contact_model=False, repair_gravity=False,
                                              warmup=0))
    save_guard(old, tmp_path)
    # what a save before the settings moved into the arrays' header wrote: bare arrays
    save_file({k: v.copy(order="C") for k, v in old.stats.items()},
              str(tmp_path / "guard.safetensors"))
    meta = json.loads((tmp_path / "guard.json").read_text())
    for key in ("two_sided", "margin2", "explain", "imu_attribution", "imu_delay", "imu_jump",
                "contact_model", "contact_lags", "contact_hidden", "contact_epochs",
                "repair_gravity", "warmup"):
        del meta["config"][key]
    (tmp_path / "guard.json").write_text(json.dumps(meta))
    back = load_guard(tmp_path)
    assert not back.cfg.two_sided and not back.cfg.explain and back.names == old.names
    assert not back.cfg.imu_attribution and not back.cfg.contact_model
    assert not back.cfg.repair_gravity and back.cfg.warmup == 0
    faulty = inject(load_episodes(recorded), "bias", "joint_pos", 4,
                    3 * std_of(recorded, "joint_pos")[4])
    a, b = run(old, faulty), run(back, faulty)
    assert a[:, -1].any() and (a == b).all()


@pytest.fixture(scope="module")
def fitted_loose(recorded) -> SensorGuard:
    # ridge 30 (as in the explaining-away test): on these 1,200 steps a looser fit leaves
    # single healthy channels flagged by a gyro bias through their predictors
    return fit_guard(recorded, cfg=GuardConfig(ridge=30.0))


@pytest.mark.parametrize("sensor,ch", [("ang_vel", 0), ("ang_vel", 1), ("gravity", 1)])
def test_the_imu_check_blames_the_half_that_lies(fitted_loose, recorded, sensor, ch):
    """A 3-std bias on the gyro or on the gravity vector: with attribution the faulty half
    is flagged within 10 steps and the other half never; without it, both halves."""
    guard, data = fitted_loose, load_episodes(recorded)
    faulty = inject(data, "bias", sensor, ch, 3 * std_of(recorded, sensor)[ch])
    halves = {s: slice(OFFSET[s], OFFSET[s] + 3) for s in ("ang_vel", "gravity")}
    other = "gravity" if sensor == "ang_vel" else "ang_vel"
    for attribution in (True, False):
        g = SensorGuard(replace(guard.cfg, imu_attribution=attribution), guard.stats)
        flags = run(g, faulty)
        valid = np.arange(flags.shape[1])[None] < data["length"][:, None]
        assert not flags[:, ONSET - 1].any()
        assert flags[:, ONSET + 9, halves[sensor]].any(1).all()
        blamed = (flags[:, :, halves[other]].any(2) & valid).any(1)
        assert not blamed.any() if attribution else blamed.all()


@pytest.mark.parametrize("foot", [0, 3])
def test_a_stuck_foot_contact_is_flagged_within_10_steps_of_showing(fitted, foot):
    """A contact held at its onset reading lies once the foot's true contact changes; the
    contact network's statistic fires within 10 steps of that, and the guard flags that
    contact and nothing else."""
    guard, data = fitted
    faulty = {s: data[s].copy() for s in INPUT_SENSORS}
    c = faulty["foot_contact"][:, :, foot]
    c[:, ONSET:] = c[:, ONSET:ONSET + 1]
    e = np.arange(len(c))
    shows = np.array([ONSET + np.flatnonzero(c[i, ONSET:] != data["foot_contact"][i, ONSET:, foot])[0]
                      for i in e])
    assert (shows + 10 < data["length"]).all()  # the gait changes every foot's contact
    g = SensorGuard(guard.cfg, guard.stats, guard.sensors, len(e), guard.dt)
    col = OFFSET["foot_contact"] + foot
    row = g.names.index(f"contact:{col}")
    fired, flags = [], []
    for t in range(int(shows.max()) + 10):
        stat = g.statistics({s: faulty[s][:, t] for s in INPUT_SENSORS})
        g.flags |= g.accused(stat)
        fired.append(stat[:, row] > g.stats["threshold"][row])
        flags.append(g.flags.copy())
    fired, flags = np.stack(fired, 1), np.stack(flags, 1)
    assert all(fired[i, shows[i]:shows[i] + 10].any() for i in e)
    assert flags[e, shows + 9, col].all()
    assert not np.delete(flags[e, shows + 9], col, axis=1).any()


def test_a_flagged_gravity_vector_is_repaired_from_the_gyro(fitted_loose, recorded):
    """A 3-std bias on the gravity vector: once flagged, repair() feeds the last trusted
    gravity vector carried forward by the gyro (within 4 degrees of the true readings on
    average, where the biased ones are off by more than 10) and removes nothing of it; without
    repair_gravity the gravity vector is removed instead."""
    data = load_episodes(recorded)
    faulty = inject(data, "bias", "gravity", 1, 3 * std_of(recorded, "gravity")[1])
    e, steps = len(data["length"]), int(data["length"].min())
    for repair in (True, False):
        g = SensorGuard(replace(fitted_loose.cfg, repair_gravity=repair), fitted_loose.stats,
                        num_envs=e)
        fed, removed = [], []
        for t in range(steps):
            obs = {s: faulty[s][:, t] for s in INPUT_SENSORS}
            g.update(obs)
            fixed, rm = g.repair(obs)
            fed.append(fixed["gravity"])
            removed.append(rm["gravity"].any(1))
        fed, removed = np.stack(fed, 1), np.stack(removed, 1)
        flagged_by = ONSET + 10
        if not repair:
            assert removed[:, flagged_by:].all() and np.array_equal(fed, faulty["gravity"][:, :steps])
            continue
        assert g.repairs and not removed.any()
        true = data["gravity"][:, flagged_by:steps]

        def angle(a: np.ndarray, true: np.ndarray = true) -> np.ndarray:
            cos = (a * true).sum(-1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(true, axis=-1)
            return np.degrees(np.arccos(np.clip(cos, -1, 1)))

        # against the true readings, which carry the simulator's noise (a reading is ~2
        # degrees from the mean of its five neighbours): 3.3 on average when written
        off, ours = angle(faulty["gravity"][:, flagged_by:steps]), angle(fed[:, flagged_by:])
        assert off.min() > 10 and ours.mean() < 4 and np.quantile(ours, 0.95) < 7

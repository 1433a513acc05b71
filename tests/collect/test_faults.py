"""Each fault model against its definition, value by value, on a synthetic stream."""

from __future__ import annotations

import numpy as np
import pytest

from msta.collect.faults import (
    FAULT_TYPES,
    FaultInjector,
    FaultSpec,
    FaultyActor,
    split_faults,
    std_from_stats,
)
from msta.data.sensors import get

N, STEPS, DT = 6, 200, 0.02
SENSORS = ("joint_pos", "joint_vel", "ang_vel", "gravity", "foot_contact", "command")
STD = {"joint_pos": np.linspace(0.1, 1.2, 12), "joint_vel": np.linspace(1.0, 3.0, 12),
       "ang_vel": np.array([0.5, 0.7, 0.9]), "gravity": np.array([0.1, 0.1, 0.02])}


def stream(steps: int = STEPS, seed: int = 1) -> list[dict[str, np.ndarray]]:
    """Synthetic observations: smooth continuous channels, random 0/1 contacts."""
    rng = np.random.default_rng(seed)
    out = []
    for t in range(steps):
        obs = {s: (np.sin(0.1 * t + np.arange(N)[:, None] + np.arange(get(s).dim))
                   + 0.01 * rng.standard_normal((N, get(s).dim))).astype(np.float32)
               for s in SENSORS if s != "foot_contact"}
        obs["foot_contact"] = (rng.random((N, 4)) < 0.5).astype(np.float32)
        out.append(obs)
    return out


def run(spec: FaultSpec, seed: int = 0, steps: int = STEPS):
    inj = FaultInjector(spec, N, STD, dt=DT, seed=seed)
    obs = stream(steps)
    outs, active = [], []
    for o in obs:
        outs.append(inj.apply(o))
        active.append(inj.active.copy())
    return inj, obs, outs, np.array(active)


def faulty_part(spec, obs, outs, s):
    """(T, N, c) true and delivered values of sensor s's fault channels."""
    idx = spec.channels[s]
    return (np.stack([o[s][:, idx] for o in obs]).astype(np.float64),
            np.stack([o[s][:, idx] for o in outs]).astype(np.float64))


def check_untouched(spec, obs, outs, active):
    """Before onset nothing changes; other channels and sensors never change."""
    for s in SENSORS:
        for t in range(len(obs)):
            x, y = obs[t][s], outs[t][s]
            assert y.dtype == x.dtype and y.shape == x.shape
            keep = np.ones(x.shape[1], dtype=bool)
            if s in spec.channels:
                keep[spec.channels[s]] = False
                np.testing.assert_array_equal(y[~active[t]], x[~active[t]])
            np.testing.assert_array_equal(y[:, keep], x[:, keep])


def test_active_from_the_onset_drawn_in_the_window():
    inj, _obs, _outs, active = run(FaultSpec("bias", 3, "joint_pos:5"))
    lo, hi = round(1.0 / DT), round(3.0 / DT)
    assert ((inj.onset >= lo) & (inj.onset <= hi)).all() and len(set(inj.onset)) > 1
    for e in range(N):
        np.testing.assert_array_equal(active[:, e], np.arange(STEPS) >= inj.onset[e])


@pytest.mark.parametrize("target", ["joint_pos:5", "encoder:2", "ang_vel", "joint_vel:3,7"])
def test_stuck_holds_the_reading_at_onset(target):
    spec = FaultSpec("stuck", 0, target)
    inj, obs, outs, active = run(spec)
    check_untouched(spec, obs, outs, active)
    for s in spec.channels:
        true, got = faulty_part(spec, obs, outs, s)
        for e in range(N):
            on = inj.onset[e]
            np.testing.assert_array_equal(got[on:, e], np.broadcast_to(true[on, e],
                                                                       got[on:, e].shape))
            assert not np.allclose(true[on + 5, e], true[on, e])  # the stream moved


def test_bias_adds_k_std_from_onset():
    spec = FaultSpec("bias", 3, "joint_pos:5")
    _inj, obs, outs, active = run(spec)
    check_untouched(spec, obs, outs, active)
    true, got = faulty_part(spec, obs, outs, "joint_pos")
    np.testing.assert_allclose(got[active], true[active] + 3 * STD["joint_pos"][5], rtol=1e-6)


def test_drift_adds_k_std_per_second_since_onset():
    spec = FaultSpec("drift", 0.5, "encoder:4")
    inj, obs, outs, active = run(spec)
    check_untouched(spec, obs, outs, active)
    for s in ("joint_pos", "joint_vel"):
        true, got = faulty_part(spec, obs, outs, s)
        for e in range(N):
            on = inj.onset[e]
            since = (np.arange(on, STEPS) - on) * DT
            np.testing.assert_allclose(got[on:, e, 0],
                                       true[on:, e, 0] + 0.5 * STD[s][4] * since,
                                       rtol=1e-5, atol=1e-6)


def test_noise_adds_gaussian_of_k_std():
    spec = FaultSpec("noise", 3, "ang_vel", onset_s=(0.0, 0.0))
    _inj, obs, outs, active = run(spec, steps=400)
    assert active.all()
    true, got = faulty_part(spec, obs, outs, "ang_vel")
    z = (got - true) / (3 * STD["ang_vel"])  # (T, N, 3) should be N(0, 1)
    assert abs(z.mean()) < 0.05 and abs(z.std() - 1) < 0.05
    assert abs(np.corrcoef(z[:-1].ravel(), z[1:].ravel())[0, 1]) < 0.05  # fresh every step


def test_spikes_hit_about_rate_with_plus_minus_k_std():
    spec = FaultSpec("spikes", 5, "gravity", rate=0.2, onset_s=(0.0, 0.5))
    _inj, obs, outs, active = run(spec, steps=400)
    check_untouched(spec, obs, outs, active)
    true, got = faulty_part(spec, obs, outs, "gravity")
    d = (got - true)[active] / STD["gravity"]  # (steps active, 3)
    hit = np.abs(d) > 1e-3
    np.testing.assert_allclose(np.abs(d[hit]), 5.0, rtol=1e-4)
    assert abs(hit.mean() - 0.2) < 0.03 and abs((d[hit] > 0).mean() - 0.5) < 0.08


def test_spikes_flip_a_binary_sensor():
    spec = FaultSpec("spikes", 0, "foot_contact:1", rate=0.3, onset_s=(0.0, 0.0))
    _inj, obs, outs, _active = run(spec, steps=400)
    true, got = faulty_part(spec, obs, outs, "foot_contact")
    flipped = got != true
    np.testing.assert_array_equal(got[flipped], 1 - true[flipped])
    assert abs(flipped.mean() - 0.3) < 0.03


def test_dropout_holds_the_last_delivered_reading():
    spec = FaultSpec.parse("dropout:0.25:joint_pos:3,7")
    assert spec.rate == 0.25
    _inj, obs, outs, active = run(spec, steps=400)
    check_untouched(spec, obs, outs, active)
    true, got = faulty_part(spec, obs, outs, "joint_pos")
    fresh = (got == true).all(axis=2)  # (T, N) reading delivered
    held = ~fresh
    assert not held[~active].any()
    assert abs(held[active].mean() - 0.25) < 0.04
    for t, e in zip(*np.nonzero(held)):  # a missing step repeats the previous delivery
        np.testing.assert_array_equal(got[t, e], got[t - 1, e])


def test_scale_multiplies():
    spec = FaultSpec("scale", 1.5, "joint_vel:4")
    _inj, obs, outs, active = run(spec)
    check_untouched(spec, obs, outs, active)
    true, got = faulty_part(spec, obs, outs, "joint_vel")
    np.testing.assert_allclose(got[active], 1.5 * true[active], rtol=1e-6)


def test_input_is_not_modified_and_other_sensors_are_shared():
    inj = FaultInjector(FaultSpec("bias", 3, "ang_vel", onset_s=(0, 0)), N, STD)
    obs = stream(1)[0]
    before = {k: v.copy() for k, v in obs.items()}
    out = inj.apply(obs)
    for k in obs:
        np.testing.assert_array_equal(obs[k], before[k])
    assert out["joint_pos"] is obs["joint_pos"] and out["ang_vel"] is not obs["ang_vel"]


def test_reset_draws_a_new_onset_and_seeds_reproduce():
    spec = FaultSpec("noise", 3, "encoder:2")
    a, _, outs_a, _ = run(spec, seed=5)
    _b, _, outs_b, _ = run(spec, seed=5)
    for x, y in zip(outs_a, outs_b):
        for s in x:
            np.testing.assert_array_equal(x[s], y[s])
    c, _, _outs_c, _ = run(spec, seed=6)
    assert not np.array_equal(a.onset, c.onset)
    first = a.onset.copy()
    a.reset(np.array([0, 1, 2]))
    assert (a.t[:3] == 0).all() and (a.t[3:] == STEPS).all() and not a.active[:3].any()
    np.testing.assert_array_equal(a.onset[3:], first[3:])
    assert not np.array_equal(a.onset[:3], first[:3])


def test_absent_names_the_active_fault_channels():
    spec = FaultSpec("stuck", 0, "encoder:2")
    inj = FaultInjector(spec, N, STD, seed=3)
    for o in stream(120):
        inj.apply(o)
        ab = inj.absent()
        assert set(ab) == {"joint_pos", "joint_vel"}
        for m in ab.values():
            assert m.shape == (N, 12)
            np.testing.assert_array_equal(m[:, 2], inj.active)
            assert not np.delete(m, 2, axis=1).any()


class Recorder:
    """A minimal actor: records what it was called with, returns zeros."""

    sensors = ("joint_pos", "joint_vel", "ang_vel")

    def __init__(self) -> None:
        self.calls: list[tuple[dict, dict | None]] = []

    def reset(self, ids) -> None:
        pass

    def act(self, obs, absent=None):
        self.calls.append((obs, absent))
        return np.zeros((N, 12), dtype=np.float32)


def test_faulty_actor_oracle_removes_exactly_the_active_channels():
    spec = FaultSpec("bias", 3, "encoder:2")
    student = Recorder()
    actor = FaultyActor(student, FaultInjector(spec, N, STD, seed=0), oracle=True, record=True)
    actor.reset(np.arange(N))
    raw = stream(160)  # onsets <= 150 steps
    for o in raw:
        actor.act(o)
    onset = actor.injector.onset
    for t, (obs, absent) in enumerate(student.calls):
        on = t >= onset
        # the student gets the faulty reading, and the removal of exactly those channels
        np.testing.assert_allclose(obs["joint_pos"][:, 2],
                                   raw[t]["joint_pos"][:, 2] + 3 * STD["joint_pos"][2] * on,
                                   rtol=1e-6)
        if not on.any():
            assert absent is None
            continue
        for s in ("joint_pos", "joint_vel"):
            np.testing.assert_array_equal(absent[s][:, 2], on)
            assert not np.delete(absent[s], 2, axis=1).any()
        assert set(absent) == {"joint_pos", "joint_vel"}
    det = actor.detections()
    np.testing.assert_array_equal(det["detected"], onset)
    assert (det["delay"] == 0).all() and (det["false_alarms"] == 0).all()


def test_faulty_actor_unguarded_passes_no_removal():
    student = Recorder()
    actor = FaultyActor(student, FaultInjector(FaultSpec("stuck", 0, "ang_vel"), N, STD))
    actor.reset(np.arange(N))
    for o in stream(100):
        actor.act(o)
    assert all(a is None for _, a in student.calls)
    assert (actor.detections()["detected"] == -1).all()


def test_one_string_form_round_trips():
    for text in ("stuck:0:encoder:3", "bias:3:joint_pos:5", "noise:3:ang_vel",
                 "spikes:5:gravity", "dropout:0.2:foot_contact", "drift:0.5:joint_pos:2",
                 "scale:1.5:joint_vel:4", "spikes:5:gravity/rate=0.05",
                 "bias:1:joint_pos:3,7/onset=0.5-2"):
        spec = FaultSpec.parse(text)
        assert str(spec) == text and FaultSpec.parse(str(spec)) == spec
    assert FaultSpec.parse("bias:3:joint_pos:3,7").channels["joint_pos"].tolist() == [3, 7]
    assert FaultSpec.parse("x:1:ang_vel/onset=2".replace("x", "bias")).onset_s == (2.0, 2.0)
    assert {t for t in FAULT_TYPES} == {FaultSpec.parse(f"{t}:1:ang_vel").type
                                        for t in FAULT_TYPES}
    assert split_faults("bias:3:joint_pos:3,7, noise:3:ang_vel,stuck:0:encoder:1,2") == [
        "bias:3:joint_pos:3,7", "noise:3:ang_vel", "stuck:0:encoder:1,2"]


@pytest.mark.parametrize("text", [
    "bias:3", "wobble:3:ang_vel", "bias:x:ang_vel", "bias:3:command", "bias:3:joint_pos:12",
    "bias:3:joint_pos:1,1", "bias:3:encoder", "bias:3:joint_pos:a", "noise:-1:ang_vel",
    "bias:3:foot_contact", "drift:1:foot_contact:0", "spikes:5:gravity/rate=2",
    "spikes:5:gravity/speed=2", "bias:3:ang_vel/onset=3-1", "bias:inf:ang_vel",
    "dropout:0.2:ang_vel/rate=0.3", "bias:3:ang_vel/onset=0-inf",
    "bias:3:ang_vel/onset=1e300-1e300", "bias:3:ang_vel/onset=nan", "bias:1e300:ang_vel",
    "bias:3:encoder:"])
def test_bad_specs_are_one_line_errors(text):
    with pytest.raises(ValueError) as e:
        FaultSpec.parse(text)
    assert "\n" not in str(e.value) and str(e.value)


def test_std_faults_need_the_statistics():
    with pytest.raises(KeyError, match="no std for sensor 'ang_vel'"):
        FaultInjector(FaultSpec("bias", 3, "ang_vel"), N, {})
    FaultInjector(FaultSpec("stuck", 0, "ang_vel"), N, {})  # stuck needs none


def test_std_from_stats_reads_the_processor_columns():
    stats = {"observation.joint_pos": {"mean": [0.0] * 12, "std": [0.0] + [0.5] * 11},
             "observation.ang_vel": {"mean": [0.0] * 3, "std": [2.0] * 3}}
    std = std_from_stats(stats, ("joint_pos", "ang_vel", "foot_contact", "gravity"))
    assert set(std) == {"joint_pos", "ang_vel"}
    assert std["joint_pos"][0] == 1.0 and std["joint_pos"][1] == 0.5

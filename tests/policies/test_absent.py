"""Per-sample channel removal (``absent``): the same as ``channels`` per sample, the removed
values are ignored, actors pass it on, and without it nothing changes."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from msta_test_helpers import random_batch  # registered by tests/conftest.py

from msta.data import sensors
from msta.policies.actor import SplitActor, StudentActor
from msta.policies.baselines import GRUPolicy
from msta.policies.factory import make_policy
from msta.policies.input_spec import InputSpec
from msta.policies.msta.removal import num_kept
from msta.policies.registry import get_config_class

T = 6
NAMES = ("joint_pos", "joint_vel", "ang_vel", "gravity", "foot_contact", "command",
         "last_action")

pytestmark = pytest.mark.usefixtures("one_thread")

#: every student that takes per-sample removal (tiny presets; rma_tcn's convolutions fit T)
CASES = [
    ("msta", {}),
    ("msta", {"learnable_mask": True}),
    ("gru", {}),
    ("rma_tcn", {"conv_kernels": (3, 2), "conv_strides": (1, 1)}),
    ("tert_concat", {}),
    ("tert_separate", {}),
    ("mlp", {}),
    ("msta", {"attention": "step", "num_layers": 2}),
    ("msta", {"attention": "axial", "num_layers": 2}),
]
IDS = [n + ("_mask" if o.get("learnable_mask") else f"_{o['attention']}" if o.get("attention")
            else "")
       for n, o in CASES]


def stats_for(cfg) -> dict[str, dict[str, list[float]]]:
    g = torch.Generator().manual_seed(0)
    stats = {sensors.get(n).column: {
        "mean": (0.1 * torch.randn(sensors.get(n).dim, generator=g)).tolist(),
        "std": [1.0] * sensors.get(n).dim} for n in cfg.input_sensors}
    stats["action"] = {"mean": [0.0] * 12, "std": [0.5] * 12}
    return stats


def make(name: str, overrides: dict | None = None):
    torch.manual_seed(0)
    cfg = get_config_class(name).from_preset("tiny", history=T, **(overrides or {}))
    return make_policy(cfg, stats_for(cfg)).eval()


def batch(B: int = 4, seed: int = 3, padded: bool = True) -> dict[str, torch.Tensor]:
    b = random_batch(B=B, steps=T, seed=seed, names=NAMES)
    if padded:  # some samples start their episode inside the window
        pad = torch.zeros(B, T, dtype=torch.bool)
        pad[1, :2] = True
        pad[B - 1, :4] = True
        b["pad"] = pad
    return b


def absent_of(B: int, removed: dict[str, list[int]], rows=None) -> dict[str, torch.Tensor]:
    """(B, dim) masks: channels ``removed`` of sensor s absent in samples ``rows`` (all)."""
    out = {}
    for s, ch in removed.items():
        m = torch.zeros(B, sensors.get(s).dim, dtype=torch.bool)
        for r in range(B) if rows is None else rows:
            m[r, ch] = True
        out[s] = m
    return out


def without(b: dict, removed: dict[str, list[int]], rows=None):
    """The batch with channels ``removed`` left out (and the ``channels`` saying so)."""
    rows = slice(None) if rows is None else rows
    out = {k: v[rows] for k, v in b.items()}
    channels = {}
    for s, ch in removed.items():
        keep = [c for c in range(sensors.get(s).dim) if c not in ch]
        if not keep:  # a whole sensor: left out of the batch
            del out[s]
            continue
        out[s] = out[s][..., keep]
        channels[s] = keep
    return out, channels


REMOVED = {"joint_pos": [3, 7], "joint_vel": [3], "ang_vel": [0, 1, 2]}


@pytest.mark.parametrize(("name", "overrides"), CASES, ids=IDS)
def test_same_removal_on_every_sample_equals_channels(name, overrides):
    policy = make(name, overrides)
    b = batch()
    got = policy.act(b, absent=absent_of(4, REMOVED))
    want = policy.act(*without(b, REMOVED))
    if name == "msta" and not overrides.get("learnable_mask"):
        # MSTA drops the tokens: the same tokens meet in attention, but in another order
        # (and padded ones removed by another route), so sums round differently
        torch.testing.assert_close(got, want, atol=1e-5, rtol=0)
    else:  # placeholders / mask tokens replace exactly the same values: bit-exact
        assert torch.equal(got, want)
    assert not torch.allclose(got, policy.act(b), atol=1e-4)  # the removal did something


@pytest.mark.parametrize(("name", "overrides"), CASES, ids=IDS)
def test_per_sample_removal_equals_each_sample_alone(name, overrides):
    policy = make(name, overrides)
    b = batch(B=2, padded=False)
    b["pad"] = torch.tensor([[True] * 2 + [False] * (T - 2), [False] * T])
    removed = {"joint_pos": [5], "gravity": [2]}
    got = policy.act(b, absent=absent_of(2, removed, rows=[0]))  # sample 0 only
    alone0 = policy.act(*without(b, removed, rows=[0]))
    alone1 = policy.act({k: v[[1]] for k, v in b.items()})
    torch.testing.assert_close(got, torch.cat([alone0, alone1]), atol=1e-5, rtol=0)


@pytest.mark.parametrize(("name", "overrides"), CASES, ids=IDS)
def test_absent_values_are_ignored_present_ones_are_not(name, overrides):
    policy = make(name, overrides)
    b = batch()
    absent = absent_of(4, {"joint_pos": [2], "joint_vel": [2]}, rows=[0, 2])
    base = policy.act(b, absent=absent)
    changed = {k: v.clone() for k, v in b.items()}
    changed["joint_pos"][[0, 2], :, 2] += 3.0  # the absent channel of samples 0 and 2
    changed["joint_vel"][0, :, 2] -= 2.5
    assert torch.equal(policy.act(changed, absent=absent)[[0, 2]], base[[0, 2]])
    changed["joint_pos"][[0, 2], :, 4] += 3.0  # a present channel
    assert not torch.allclose(policy.act(changed, absent=absent)[[0, 2]], base[[0, 2]],
                              atol=1e-4)
    other = {k: v.clone() for k, v in b.items()}
    other["joint_pos"][1, :, 2] += 3.0  # channel 2 is present in sample 1
    assert not torch.allclose(policy.act(other, absent=absent)[1], base[1], atol=1e-4)


def test_msta_random_removal_counts_each_samples_remaining_tokens():
    """With mask_ratio α, sample b keeps num_kept(N_b, α) of its N_b present tokens."""
    policy = make("msta")
    b = batch(B=3, padded=False)
    absent = absent_of(3, {"joint_pos": list(range(12))}, rows=[0])  # 12 T tokens fewer
    absent["ang_vel"] = torch.tensor([[False] * 3, [True, False, False], [False] * 3])
    inputs = policy.processor.discretize(b)
    inputs.absent = absent
    for alpha in (0.0, 0.3, 0.75):
        x, attn = policy.model.embed(inputs, alpha, torch.Generator().manual_seed(0))
        n = 49 * T - torch.tensor([12 * T, T, 0])
        want = [num_kept(int(k), alpha) if alpha else int(k) for k in n]
        visible = attn[:, 0, 0, :-1].sum(1) if attn is not None else None
        assert visible.tolist() == want and x.shape[1] == max(want) + 1


@pytest.mark.parametrize(("name", "overrides"), [CASES[0], CASES[2]], ids=IDS[:1] + IDS[2:3])
def test_random_removal_with_absent_is_seeded_and_leaves_absent_out(name, overrides):
    policy = make(name, overrides)
    b = batch()
    absent = absent_of(4, {"joint_pos": [0, 1]}, rows=[0, 3])

    def run(x):
        return policy.act(x, mask_ratio=0.5, generator=torch.Generator().manual_seed(7),
                          absent=absent)

    first = run(b)
    assert torch.equal(first, run(b))
    changed = {k: v.clone() for k, v in b.items()}
    changed["joint_pos"][[0, 3], :, :2] += 3.0
    assert torch.equal(run(changed)[[0, 3]], first[[0, 3]])


@pytest.mark.parametrize(("name", "overrides"), [CASES[0], CASES[2]], ids=IDS[:1] + IDS[2:3])
def test_loss_takes_absent_and_trains_through_it(name, overrides):
    policy = make(name, overrides).train()
    b = batch()
    b["action"] = torch.randn(4, 12, generator=torch.Generator().manual_seed(1))
    loss, metrics = policy.loss(b, mask_ratio=0.0, absent=absent_of(4, REMOVED, rows=[0]))
    loss.backward()
    assert metrics["loss"] > 0
    assert all(p.grad is not None for p in policy.parameters() if p.requires_grad)
    plain, _ = policy.loss(b, mask_ratio=0.0)
    assert not torch.isclose(loss.detach(), plain.detach())


@pytest.mark.parametrize(("name", "overrides"), CASES, ids=IDS)
def test_nothing_absent_is_bit_identical(name, overrides):
    policy = make(name, overrides)
    b = batch()
    g = torch.Generator().manual_seed(2)
    want = policy.act(b, mask_ratio=0.25, generator=g)
    nothing = absent_of(4, {"joint_pos": []})
    got = policy.act(b, mask_ratio=0.25, generator=torch.Generator().manual_seed(2),
                     absent=nothing)
    assert torch.equal(got, want)
    # a channel that ``channels`` left out already: nothing more to remove
    part, channels = without(b, {"joint_pos": [4]})
    want = policy.act(part, channels)
    assert torch.equal(policy.act(part, channels, absent=absent_of(4, {"joint_pos": [4]})), want)


def test_bad_absent_and_students_without_it():
    policy = make("gru")
    b = batch()
    with pytest.raises(ValueError, match=r"absent\['joint_pos'\] must be a bool array"):
        policy.act(b, absent={"joint_pos": torch.zeros(4, 11, dtype=torch.bool)})
    with pytest.raises(ValueError, match="must be a bool array"):
        policy.act(b, absent={"joint_pos": torch.zeros(4, 12)})
    with pytest.raises(ValueError, match="not an input of this policy"):
        policy.act(b, absent={"height_map": torch.zeros(4, 1, dtype=torch.bool)})

    class NoRemoval(GRUPolicy):
        supports_absent = False

    other = NoRemoval(policy.config, policy.processor)
    assert policy.supports_absent and not NoRemoval.supports_absent
    with pytest.raises(NotImplementedError, match="NoRemoval cannot remove channels per sample"):
        other.act(b, absent=absent_of(4, {"joint_pos": [1]}))
    other.act(b)  # without it: fine


def obs_seq(n: int, steps: int, seed: int = 0) -> list[dict[str, np.ndarray]]:
    rng = np.random.default_rng(seed)
    return [{s: rng.normal(size=(n, sensors.get(s).dim)).astype(np.float32) for s in NAMES}
            for _ in range(steps)]


def env_absent(n: int, removed: dict[str, list[int]], envs) -> dict[str, np.ndarray]:
    return {s: m.numpy() for s, m in absent_of(n, removed, rows=envs).items()}


@pytest.mark.parametrize(("name", "overrides"), [CASES[0], CASES[2]], ids=IDS[:1] + IDS[2:3])
def test_student_actor_passes_absent_on(name, overrides):
    policy = make(name, overrides)
    spec = InputSpec(dead_joints=(1,))
    with_it, plain = StudentActor(policy, 3, spec), StudentActor(policy, 3, spec)
    absent = env_absent(3, {"joint_pos": [1, 6], "joint_vel": [6]}, envs=[0])  # 1: dead
    for obs in obs_seq(3, 4):
        got = with_it.act(obs, absent=absent)
        window = plain.window(obs)
        want = policy.act(window, plain.channels, generator=torch.Generator(),
                          absent={k: torch.from_numpy(v) for k, v in absent.items()})
        np.testing.assert_array_equal(got, want.numpy())
    unremoved = policy.act(window, plain.channels).numpy()
    assert not np.allclose(got[0], unremoved[0], atol=1e-4)
    np.testing.assert_allclose(got[1:], unremoved[1:], atol=1e-5, rtol=0)
    # removing only a dead joint's channels changes nothing: bit-identical to no absent
    a, b = StudentActor(policy, 3, spec), StudentActor(policy, 3, spec)
    for obs in obs_seq(3, 3, seed=1):
        np.testing.assert_array_equal(
            a.act(obs, absent=env_absent(3, {"joint_pos": [1]}, envs=[0, 2])), b.act(obs))
    with pytest.raises(ValueError, match=r"absent\['ang_vel'\] must be a bool array"):
        a.act(obs, absent={"ang_vel": np.zeros((2, 3), bool)})


def test_split_actor_splits_absent_per_group():
    policy = make("msta")
    ids = [np.array([0, 3]), np.array([1, 2])]
    split = SplitActor([(i, StudentActor(policy, 2)) for i in ids])
    alone = [StudentActor(policy, 2) for _ in ids]
    absent = env_absent(4, {"joint_pos": [0, 8], "gravity": [1]}, envs=[1, 3])
    for obs in obs_seq(4, 3):
        got = split.act(obs, absent=absent)
        for i, actor in zip(ids, alone):
            want = actor.act({k: v[i] for k, v in obs.items()},
                             absent={k: v[i] for k, v in absent.items()})
            np.testing.assert_array_equal(got[i], want)
    plain = SplitActor([(i, StudentActor(policy, 2)) for i in ids])
    for obs in obs_seq(4, 3):
        ref = plain.act(obs)
    # envs 0 and 2 had nothing removed (batched with removals: MSTA's sums may round apart)
    np.testing.assert_allclose(got[[0, 2]], ref[[0, 2]], atol=1e-5, rtol=0)
    assert not np.allclose(got[[1, 3]], ref[[1, 3]], atol=1e-4)


@pytest.mark.parametrize("learnable_mask", [False, True])
def test_an_absent_channel_of_an_encoded_sensor_removes_the_whole_sensor(learnable_mask):
    """height_map is read by an MLP as a whole: any absent channel removes all its tokens."""
    from msta.policies.msta import MSTAConfig, MSTAPolicy
    from msta.policies.msta.processor_msta import MSTAProcessor

    names = (*NAMES, "height_map")
    torch.manual_seed(0)
    cfg = MSTAConfig.from_preset("tiny", input_sensors=names, history=T,
                                 learnable_mask=learnable_mask)
    stats = {sensors.get(n).column: {"mean": [0.0] * sensors.get(n).dim,
                                     "std": [1.0] * sensors.get(n).dim} for n in names}
    policy = MSTAPolicy(cfg, MSTAProcessor(names, {**stats, **stats_for(cfg)})).eval()
    b = random_batch(B=2, steps=T, seed=5, names=names)
    hm = torch.zeros(2, sensors.get("height_map").dim, dtype=torch.bool)
    hm[0, 17] = True
    got = policy.act(b, absent={"height_map": hm})
    alone0 = policy.act({k: v[[0]] for k, v in b.items() if k != "height_map"})
    alone1 = policy.act({k: v[[1]] for k, v in b.items()})
    torch.testing.assert_close(got, torch.cat([alone0, alone1]), atol=1e-5, rtol=0)

"""MLP-encoded sensor tokens (the height_map extension) and adding a sensor to a student."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.data import derived, sensors
from msta.data import features as F
from msta.policies.msta import MSTAConfig, MSTAPolicy
from msta.policies.msta.processor_msta import MSTAProcessor

T = 4
FULL = (*sensors.STUDENT_SENSORS, "height_map")
K = sensors.get("height_map").encoder_tokens


def unit_stats(names) -> dict:
    stats = {sensors.get(n).column: {"mean": [0.0] * sensors.get(n).dim,
                                     "std": [1.0] * sensors.get(n).dim} for n in names}
    return {**stats, "action": {"mean": [0.0] * 12, "std": [1.0] * 12}}


def make(inputs=FULL, **kw) -> MSTAPolicy:
    torch.manual_seed(0)
    cfg = MSTAConfig.from_preset("tiny", input_sensors=inputs, history=T, **kw)
    return MSTAPolicy(cfg, MSTAProcessor(inputs, unit_stats(inputs)))


def window(names, B=3, seed=0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    batch = {n: torch.randn(B, T, sensors.get(n).dim, generator=g) for n in names}
    if "foot_contact" in batch:
        batch["foot_contact"] = (batch["foot_contact"] > 0).float()
    return batch


def tokens_seen(policy: MSTAPolicy, batch, **kw) -> int:
    seen = []
    hook = policy.model.blocks[0].register_forward_pre_hook(lambda m, a: seen.append(a[0].shape[1]))
    try:
        policy(batch, **kw)
    finally:
        hook.remove()
    return seen[0]


def test_height_map_is_an_extension_left_out_of_every_default():
    spec = sensors.get("height_map")
    assert spec.is_student_input and spec.extension and spec.dim == 17 * 11
    assert "height_map" in sensors.EXTENSION_SENSORS
    assert "height_map" not in sensors.STUDENT_SENSORS + sensors.DEFAULT_RECORDED
    assert spec.column not in F.build_features(None)
    feats = F.build_features(FULL, derived=True)
    state = derived.sources(feats)[derived.STATE_COLUMN]
    assert spec.column in feats and spec.column not in state and len(state) == 7


def test_the_simulator_reads_the_height_map_from_the_scan_with_its_own_noise(monkeypatch):
    def observe(noise: bool) -> list[dict]:
        cfg = EnvConfig(num_envs=3, nthread=1, seed=5,
                        randomization=RandomizationConfig(pool_size=2),
                        terrain=TerrainConfig(types=("stairs_up",), num_levels=2, border=2.0))
        cfg.noise.enabled = noise
        env = QuadrupedEnv(cfg)
        obs = [env.reset()]
        for _ in range(3):
            obs.append(env.step(np.zeros((3, 12), np.float32)).obs)
        return obs

    clean = observe(False)
    assert all((o["height_map"] == o["height_scan"]).all() for o in clean)
    noisy = observe(True)
    err = np.concatenate([o["height_map"] - o["height_scan"] for o in noisy])
    assert 0 < abs(err).max() <= sensors.get("height_map").noise + 1e-6
    # its noise has a stream of its own: without it, every other observation is the same
    spec = sensors.get("height_map")
    monkeypatch.setitem(sensors.SENSORS, "height_map", replace(spec, noise=0.0))
    quiet = observe(True)
    for a, b in zip(noisy, quiet, strict=True):
        assert all((a[k] == b[k]).all() for k in a if k != "height_map")
        assert (b["height_map"] == b["height_scan"]).all()


def test_encoded_sensor_gives_k_tokens_per_step_that_are_masked_like_the_others():
    policy = make().eval()
    batch = window(FULL)
    n = T * (49 + K)
    assert tokens_seen(policy, batch) == n + 1  # + <S>
    assert tokens_seen(policy, batch, mask_ratio=0.5) == n - round(n / 2) + 1
    no_map = {k: v for k, v in batch.items() if k != "height_map"}
    assert tokens_seen(policy, no_map) == T * 49 + 1
    assert tokens_seen(policy, {"height_map": batch["height_map"]}) == T * K + 1
    # the action depends on the map, and the encoder is trained through it
    other = {**batch, "height_map": batch["height_map"] + 1.0}
    assert not torch.allclose(policy.act(batch), policy.act(other))
    policy.train()
    policy(batch, mask_ratio=0.25).square().sum().backward()
    grads = [p.grad for p in policy.model.encoders["height_map"].parameters()]
    assert all(g is not None and g.abs().sum() > 0 for g in grads)


@pytest.mark.parametrize("variant", [{"learnable_mask": True}, {"value_embedding": "sensor"}])
def test_encoded_tokens_work_in_the_ablations(variant):
    policy = make(**variant).eval()
    batch = window(FULL)
    assert policy.act(batch).shape == (3, 12)
    assert policy.act({"height_map": batch["height_map"]}).shape == (3, 12)


def test_the_scalar_tokens_are_unchanged_by_an_encoded_input():
    """A model built with the map acts on the other inputs exactly as one built without it
    when given the same weights: the value tables and positions of the scalar tokens do not
    move because an encoded sensor is configured."""
    with_map, without = make(), make(inputs=sensors.STUDENT_SENSORS)
    state = {k: v for k, v in with_map.state_dict().items() if "height_map" not in k}
    without.load_state_dict(state)
    batch = window(sensors.STUDENT_SENSORS)
    torch.testing.assert_close(with_map.eval().act(batch), without.eval().act(batch),
                               rtol=0, atol=1e-6)


def test_an_encoded_sensor_is_read_whole():
    policy = make().eval()
    batch = window(FULL)
    with pytest.raises(ValueError, match="'height_map' is encoded as a whole"):
        policy.act({**batch, "height_map": batch["height_map"][..., :5]},
                   channels={"height_map": list(range(5))})


def test_with_inputs_adds_a_sensor_with_fresh_weights_and_its_statistics():
    src = make(inputs=sensors.STUDENT_SENSORS).eval()
    kept = ("command", "joint_pos", "gravity", "last_action")
    small = src.with_inputs(kept, T)
    stats = unit_stats(["height_map"])
    stats[sensors.get("height_map").column] = {"mean": [0.1] * 187, "std": [0.5] * 187}
    big = src.with_inputs((*kept, "height_map"), T, stats)
    assert big.config.input_sensors == (*small.config.input_sensors, "height_map")
    assert big.processor.stats[sensors.get("height_map").column]["std"][0] == 0.5
    batch = window(big.config.input_sensors)
    no_map = {k: v for k, v in batch.items() if k != "height_map"}
    torch.testing.assert_close(big.act(no_map), small.act(no_map), rtol=0, atol=1e-6)
    assert not torch.allclose(big.act(batch), small.act(no_map))
    # again on its own result: nothing new, the same student (msta-finetune's resume)
    again = big.with_inputs(big.config.input_sensors, T)
    torch.testing.assert_close(again.act(batch), big.act(batch), rtol=0, atol=0)
    with pytest.raises(ValueError, match="no statistics for the new input 'joint_vel'"):
        small.with_inputs((*kept, "joint_vel"), T)
    with pytest.raises(ValueError, match="'base_height' is privileged"):
        small.with_inputs((*kept, "base_height"), T, stats)

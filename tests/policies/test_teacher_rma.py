"""RMA MLP teacher: protocol contract, scaling, save/load, config errors, real env."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig
from msta.data.robot import A1, DEFAULT_POSE, load_robot
from msta.data.sensors import PRIVILEGED_SENSORS, SENSORS, STUDENT_SENSORS, get
from msta.policies.teacher.base import TEACHERS, Teacher, make_teacher
from msta.policies.teacher.imported import InputScaler, SignalSpec
from msta.policies.teacher.rma import RMAConfig, RMATeacher

SMALL = {"encoder_hidden": (16, 8), "latent_dim": 4, "policy_hidden": (8,)}


def random_obs(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {k: rng.normal(size=(n, s.dim)).astype(np.float32) for k, s in SENSORS.items()}


@pytest.fixture
def teacher() -> RMATeacher:
    torch.manual_seed(0)
    return RMATeacher()


def test_protocol_contract(teacher: RMATeacher) -> None:
    assert TEACHERS["rma"] is RMATeacher
    assert isinstance(teacher, Teacher)
    assert teacher.name == "rma"
    for name in teacher.sensors:
        get(name)  # a registry name
    assert set(teacher.sensors) == set(STUDENT_SENSORS) | (
        set(PRIVILEGED_SENSORS) - {"base_height", "true_contact"})
    obs = random_obs(7)
    a = teacher.act(obs)
    assert a.shape == (7, 12) and a.dtype == np.float32 and np.all(np.isfinite(a))
    np.testing.assert_array_equal(teacher.act(obs), a)          # deterministic
    teacher.reset(np.array([0, 3]))                              # stateless: no change
    np.testing.assert_array_equal(teacher.act(obs), a)
    # batched: each row only depends on its own observation
    one = teacher.act({k: v[2:3] for k, v in obs.items()})
    np.testing.assert_allclose(one[0], a[2], rtol=1e-5, atol=1e-6)
    assert not np.allclose(a[0], a[1])


def test_paper_architecture(teacher: RMATeacher) -> None:
    enc = [m for m in teacher.encoder if isinstance(m, torch.nn.Linear)]
    pol = [m for m in teacher.policy if isinstance(m, torch.nn.Linear)]
    assert [m.out_features for m in enc] == [512, 256, 128, 32]
    assert enc[0].in_features == 3 + 3 + 4 + 187 + 8
    assert [m.out_features for m in pol] == [256, 128, 12]
    assert pol[0].in_features == 32 + 49
    assert sum(isinstance(m, torch.nn.ELU) for m in teacher.encoder) == 3


def test_missing_sensor_is_named(teacher: RMATeacher) -> None:
    obs = random_obs(3)
    del obs["height_scan"]
    with pytest.raises(KeyError, match="height_scan"):
        teacher.act(obs)


def test_input_scaling_matches_hand_computation() -> None:
    torch.manual_seed(1)
    cfg = RMAConfig(
        privileged=[SignalSpec("base_lin_vel", scale=2.0),
                    SignalSpec("height_scan", scale=5.0, offset=-0.3, clip=5.0)],
        proprio=[SignalSpec("joint_pos", offset=[float(v) for v in DEFAULT_POSE]),
                 SignalSpec("command", scale=[2.0, 2.0, 0.25])], **SMALL)
    t = RMATeacher(cfg)
    assert t.sensors == ("base_lin_vel", "height_scan", "joint_pos", "command")
    obs = random_obs(4, seed=3)
    obs["height_scan"][0, :5] = [-3.0, 3.0, -0.3, -0.2, 0.0]
    priv = np.concatenate([obs["base_lin_vel"] * 2.0,
                           np.clip((obs["height_scan"] + 0.3) * 5.0, -5, 5)], axis=1)
    prop = np.concatenate([obs["joint_pos"] - DEFAULT_POSE,
                           obs["command"] * np.array([2.0, 2.0, 0.25])], axis=1)
    assert priv[0, 0 + 3] == -5.0 and priv[0, 1 + 3] == 5.0 and priv[0, 2 + 3] == 0.0
    with torch.no_grad():
        want = t(torch.tensor(priv, dtype=torch.float32), torch.tensor(prop, dtype=torch.float32))
    np.testing.assert_allclose(t.act(obs), want.numpy(), rtol=1e-6, atol=1e-6)


def test_save_load_round_trip_is_bit_exact(teacher: RMATeacher, tmp_path) -> None:
    teacher.save_pretrained(tmp_path / "ckpt")
    assert sorted(p.name for p in (tmp_path / "ckpt").iterdir()) == ["config.json",
                                                                     "model.safetensors"]
    assert json.loads((tmp_path / "ckpt" / "config.json").read_text())["type"] == "rma"
    loaded = RMATeacher.from_pretrained(tmp_path / "ckpt")
    assert loaded.config == teacher.config
    sd0, sd1 = teacher.state_dict(), loaded.state_dict()
    assert sd0.keys() == sd1.keys()
    for k in sd0:
        assert torch.equal(sd0[k], sd1[k]), k
    obs = random_obs(16, seed=5)
    np.testing.assert_array_equal(loaded.act(obs), teacher.act(obs))
    via_registry = make_teacher("rma", pretrained=tmp_path / "ckpt")
    np.testing.assert_array_equal(via_registry.act(obs), teacher.act(obs))


def test_custom_config_round_trip(tmp_path) -> None:
    torch.manual_seed(2)
    cfg = RMAConfig(privileged=[SignalSpec("dynamics"), SignalSpec("base_height", scale=3.0)],
                    proprio=[SignalSpec("gravity")], activation="tanh", **SMALL)
    t = RMATeacher(cfg)
    t.save_pretrained(tmp_path)
    loaded = RMATeacher.from_pretrained(tmp_path)
    assert loaded.config == cfg and loaded.sensors == ("dynamics", "base_height", "gravity")
    obs = random_obs(3)
    np.testing.assert_array_equal(loaded.act(obs), t.act(obs))


@pytest.mark.parametrize("patch, match", [
    ({"bogus": 1}, "bogus"),
    ({"activation": "gelu2"}, "gelu2"),
    ({"latent_dim": 0}, "latent_dim"),
    ({"proprio": [{"name": "joint_pos", "scale": [1.0, 2.0]}]}, "joint_pos.*2 values"),
    ({"proprio": [{"name": "not_a_sensor"}]}, "not_a_sensor"),
    ({"type": "gait"}, "gait"),
])
def test_bad_config_errors(tmp_path, patch, match) -> None:
    data = {**RMAConfig(**SMALL).to_dict(), **patch}
    with pytest.raises((ValueError, KeyError), match=match):
        RMAConfig.from_dict(data)


def test_weights_config_mismatch_and_missing_files(tmp_path) -> None:
    torch.manual_seed(0)
    RMATeacher(RMAConfig(**SMALL)).save_pretrained(tmp_path)
    data = json.loads((tmp_path / "config.json").read_text())
    data["latent_dim"] = 5
    (tmp_path / "config.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match="do not match"):
        RMATeacher.from_pretrained(tmp_path)
    (tmp_path / "model.safetensors").unlink()
    with pytest.raises(FileNotFoundError, match="model.safetensors"):
        RMATeacher.from_pretrained(tmp_path)
    with pytest.raises(ValueError, match="either config or pretrained"):
        RMATeacher(RMAConfig(), pretrained=tmp_path)


def test_drives_the_real_env() -> None:
    torch.manual_seed(0)
    teacher = make_teacher("rma")
    env = QuadrupedEnv(EnvConfig(num_envs=4, nthread=1, seed=1))
    obs = env.reset()
    actions = []
    for _ in range(10):
        a = teacher.act(obs)
        assert a.shape == (4, 12) and np.all(np.isfinite(a))
        actions.append(a)
        res = env.step(a)
        obs = res.obs
        teacher.reset(np.flatnonzero(res.done))
        assert all(np.all(np.isfinite(v)) for v in obs.values())
    # the observations change under the teacher's actions, so do the actions
    assert not np.allclose(actions[0], actions[-1])


def _walk(teacher, n: int = 40, seconds: float = 4.0, types=("flat", "smooth_slope"),
          level: int | None = None, seed: int = 3) -> tuple[float, float]:
    """(survival, mean per-step linear tracking) on two terrain types (robots alternate),
    at levels 0-1 (alternating) or all at ``level``."""
    from msta.collect.sim.terrain import TerrainConfig

    env = QuadrupedEnv(EnvConfig(num_envs=n, nthread=1, seed=seed, episode_length_s=seconds,
                                 terrain=TerrainConfig(types=types, curriculum=False)))
    env.set_tiles(np.arange(n) % 2,
                  (np.arange(n) // 2) % 2 if level is None else np.full(n, level))
    obs, alive, fell, lin = env.reset(), np.ones(n, bool), np.zeros(n, bool), []
    teacher.reset(np.arange(n))
    for _ in range(env.max_steps):
        res = env.step(teacher.act(obs))
        obs = res.obs
        lin.append(float(res.metrics["lin_vel_tracking"][alive].mean()))
        fell |= alive & res.terminated
        alive &= ~res.done
    return 1.0 - fell.mean(), float(np.mean(lin))


def test_the_shipped_teacher_walks_like_the_gait_controller_it_imitated() -> None:
    from msta.policies.teacher.config import SHIPPED_RMA, TeacherConfig, build_teacher

    cfg = TeacherConfig(type="rma", path=str(SHIPPED_RMA))  # the DART warm start
    made = json.loads((SHIPPED_RMA / "produced_by.json").read_text())
    assert made["command"].startswith("msta-train-teacher") and "--ppo.iterations=0" in made["command"]
    surv, lin = _walk(build_teacher(cfg))
    gait_surv, gait_lin = _walk(build_teacher(TeacherConfig(type="gait")))
    _, zero_lin = _walk(build_teacher(TeacherConfig(type="zero")))
    assert surv >= 0.9 and gait_surv >= 0.9
    assert lin >= 0.85 * gait_lin and lin > 2 * zero_lin, (lin, gait_lin, zero_lin)


def test_the_shipped_ppo_teacher_climbs_stairs_the_gait_controller_falls_on() -> None:
    from msta.policies.teacher.config import SHIPPED_RMA_PPO, TeacherConfig, build_teacher

    made = json.loads((SHIPPED_RMA_PPO / "produced_by.json").read_text())
    assert made["command"].startswith("msta-train-teacher") and made["iteration"] == 1900

    def stairs_survival(teacher) -> float:   # level 5 of both stair types
        return _walk(teacher, 60, 12.0, ("stairs_up", "stairs_down"), level=5, seed=5)[0]

    ppo = stairs_survival(build_teacher(TeacherConfig(type="rma", path=str(SHIPPED_RMA_PPO))))
    gait = stairs_survival(build_teacher(TeacherConfig(type="gait")))
    assert ppo >= gait + 0.15, (ppo, gait)


def test_a_new_teachers_joint_angles_are_relative_to_its_robots_default_pose():
    """RMAConfig.for_robot: the A1's is RMAConfig() as before; the Go1's reads its joint
    angles relative to the Go1's default pose (thigh 0.9, calf -1.8)."""
    assert RMAConfig.for_robot(A1).to_dict() == RMAConfig().to_dict()
    assert RMAConfig().proprio[0].offset == [float(v) for v in DEFAULT_POSE]
    go1 = load_robot("go1")
    cfg = RMAConfig.for_robot(go1, latent_dim=4)
    joint_pos = next(s for s in cfg.proprio if s.name == "joint_pos")
    assert joint_pos.offset == list(go1.default_pose) and cfg.latent_dim == 4
    scaler = InputScaler(cfg.proprio)
    obs = {s.name: np.zeros((1, get(s.name).dim)) for s in cfg.proprio}
    obs["joint_pos"] = np.array([go1.default_pose])
    assert np.abs(scaler(obs)[:, :12]).max() == 0.0  # the default pose reads 0

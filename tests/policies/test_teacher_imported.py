"""Imported teacher: TorchScript / ONNX parity with the source module, joint order and
action-convention conversions on hand-made cases, history stacking, spec errors."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from msta.collect.sim.env import QuadrupedEnv
from msta.collect.sim.env_config import EnvConfig
from msta.data.robot import DEFAULT_POSE
from msta.data.sensors import JOINT_NAMES, SENSORS, STUDENT_SENSORS, get
from msta.policies.teacher.base import TEACHERS, Teacher, make_teacher
from msta.policies.teacher.imported import ActionConverter, ActionSpec, ImportedTeacher

# torch 2.11 deprecates torch.jit; TorchScript files are still what other frameworks export
pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit:DeprecationWarning")

FORMATS = ("torchscript", "onnx")
#: a source that orders legs RR, FL, RL, FR (a 3-cycle of msta's FL, FR, RL, RR: not an
#: involution, so mixing up a permutation and its inverse shows)
ODD_ORDER = [f"{leg}_{j}" for leg in ("RR", "FL", "RL", "FR") for j in ("hip", "thigh", "calf")]


def random_obs(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {k: rng.normal(size=(n, s.dim)).astype(np.float32) for k, s in SENSORS.items()}


def mlp(in_dim: int, out_dim: int = 12, seed: int = 0) -> nn.Module:
    torch.manual_seed(seed)
    return nn.Sequential(nn.Linear(in_dim, 32), nn.ELU(), nn.Linear(32, out_dim)).eval()


def affine(in_dim: int, weight: np.ndarray | None = None, bias: np.ndarray | None = None
           ) -> nn.Module:
    """A fixed linear map ``out = x @ weight.T + bias`` (12 outputs)."""
    lin = nn.Linear(in_dim, 12)
    with torch.no_grad():
        lin.weight.copy_(torch.zeros(12, in_dim) if weight is None else torch.tensor(weight))
        lin.bias.copy_(torch.zeros(12) if bias is None else torch.tensor(bias))
    return lin.eval()


def select(in_dim: int, idx: list[int]) -> nn.Module:
    """``out[:, i] = x[:, idx[i]]``."""
    w = np.zeros((12, in_dim), dtype=np.float32)
    w[np.arange(12), idx] = 1.0
    return affine(in_dim, w)


def export(module: nn.Module, in_dim: int, fmt: str, path: Path) -> Path:
    x = torch.zeros(2, in_dim)
    if fmt == "torchscript":
        path = path.with_suffix(".pt")
        torch.jit.save(torch.jit.trace(module, x), str(path))
    else:
        path = path.with_suffix(".onnx")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torch.onnx.export(module, (x,), str(path), input_names=["obs"],
                              output_names=["actions"], dynamic_axes={"obs": {0: "batch"}},
                              dynamo=False)
    return path


def write_spec(tmp_path: Path, model: Path, inputs: list, **extra) -> Path:
    spec = tmp_path / f"{model.stem}.json"
    spec.write_text(json.dumps({"model": model.name, "inputs": inputs, **extra}, indent=1))
    return spec


def build(tmp_path: Path, module: nn.Module, fmt: str, inputs: list, in_dim: int,
          **extra) -> ImportedTeacher:
    model = export(module, in_dim, fmt, tmp_path / f"net_{fmt}")
    return ImportedTeacher.from_spec(write_spec(tmp_path, model, inputs, **extra))


LEGGED_GYM_INPUTS = [
    {"name": "ang_vel", "scale": 0.25},
    {"name": "gravity"},
    {"name": "command", "scale": [2.0, 2.0, 0.25]},
    {"name": "joint_pos", "offset": [float(v) for v in DEFAULT_POSE]},
    {"name": "joint_vel", "scale": 0.05},
    {"name": "last_action"},
]


@pytest.mark.parametrize("fmt", FORMATS)
def test_same_actions_as_the_module(tmp_path, fmt) -> None:
    net = mlp(45)
    teacher = build(tmp_path, net, fmt, LEGGED_GYM_INPUTS, 45)
    assert TEACHERS["imported"] is ImportedTeacher and isinstance(teacher, Teacher)
    assert teacher.sensors == ("ang_vel", "gravity", "command", "joint_pos", "joint_vel",
                               "last_action")
    obs = random_obs(9, seed=1)
    x = np.concatenate([obs["ang_vel"] * 0.25, obs["gravity"],
                        obs["command"] * np.array([2.0, 2.0, 0.25]),
                        obs["joint_pos"] - DEFAULT_POSE, obs["joint_vel"] * 0.05,
                        obs["last_action"]], axis=1)
    with torch.no_grad():
        want = net(torch.tensor(x, dtype=torch.float32)).numpy()
    a = teacher.act(obs)
    assert a.shape == (9, 12) and a.dtype == np.float32
    # default convention (scale 0.25 around msta's default pose) = msta's: actions unchanged
    np.testing.assert_allclose(a, want, rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(teacher.act(obs), a)       # deterministic
    teacher.reset(np.array([0, 4]))
    np.testing.assert_array_equal(teacher.act(obs), a)       # history 1: reset changes nothing
    for name in teacher.sensors:
        get(name)


@pytest.mark.parametrize("fmt", FORMATS)
def test_joint_order_permutes_inputs_and_outputs(tmp_path, fmt) -> None:
    # constant output c = 0..11 in the source's order; scale 1 around zero -> target = c
    const = build(tmp_path, affine(12, bias=np.arange(12, dtype=np.float32)), fmt,
                  [{"name": "joint_pos"}], 12, joint_order=ODD_ORDER,
                  action={"scale": 1.0, "default_pose": [0.0] * 12})
    a = const.act(random_obs(2))
    # source legs RR, FL, RL, FR hold 0-2, 3-5, 6-8, 9-11; msta order is FL, FR, RL, RR
    target = np.array([3, 4, 5, 9, 10, 11, 6, 7, 8, 0, 1, 2], dtype=np.float64)
    np.testing.assert_allclose(a, np.tile((target - DEFAULT_POSE) / 0.25, (2, 1)), atol=1e-5)

    # inputs: the source's first joint input is msta's RR_hip, its first foot is RR's
    picker = build(tmp_path, select(16, [0] * 6 + [12] * 6), fmt,
                   [{"name": "joint_pos"}, {"name": "foot_contact"}], 16,
                   joint_order=ODD_ORDER, action={"scale": 1.0, "default_pose": [0.0] * 12})
    obs = random_obs(3, seed=2)
    a = picker.act(obs)
    rr_hip, rr_foot = obs["joint_pos"][:, 9:10], obs["foot_contact"][:, 3:4]
    src_target = np.concatenate([np.repeat(rr_hip, 6, 1), np.repeat(rr_foot, 6, 1)], axis=1)
    msta_target = src_target[:, np.argsort([JOINT_NAMES.index(n) for n in ODD_ORDER])]
    np.testing.assert_allclose(a, (msta_target - DEFAULT_POSE) / 0.25, rtol=1e-5, atol=1e-5)
    # explicitly: msta's FL joints are source slots 3-5 (all RR_hip), RL slots 6-8 (RR foot)
    np.testing.assert_allclose(a[:, 2], (rr_hip[:, 0] + 1.5) / 0.25, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(a[:, 6], (rr_foot[:, 0] - 0.1) / 0.25, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(a[:, 9], (rr_hip[:, 0] + 0.1) / 0.25, rtol=1e-5, atol=1e-5)


def test_action_convention_by_hand(tmp_path) -> None:
    # source: target = 0 + 0.5 * clip(out, -1, 1); out = 0.2 for every joint -> target 0.1
    t = build(tmp_path, affine(3, bias=np.full(12, 0.2, dtype=np.float32)), "torchscript",
              [{"name": "command"}], 3,
              action={"scale": 0.5, "default_pose": [0.0] * 12, "clip": 1.0})
    a = t.act(random_obs(1))[0]
    # FL: default hip 0.1, thigh 0.8, calf -1.5 -> (0.1 - d) / 0.25
    np.testing.assert_allclose(a[:3], [0.0, -2.8, 6.4], atol=1e-5)
    # out = 3 is clipped to 1 -> target 0.5 -> FR hip (default -0.1): 0.6 / 0.25 = 2.4
    t2 = build(tmp_path, affine(3, bias=np.full(12, 3.0, dtype=np.float32)), "torchscript",
               [{"name": "command"}], 3,
               action={"scale": 0.5, "default_pose": [0.0] * 12, "clip": 1.0})
    np.testing.assert_allclose(t2.act(random_obs(1))[0, 3], 2.4, atol=1e-5)
    # msta's own action scale enters the denominator
    t3 = ImportedTeacher(tmp_path / "net_torchscript.json", msta_action_scale=0.5)
    np.testing.assert_allclose(t3.act(random_obs(1))[0, 3], 1.2, atol=1e-5)


def test_last_action_is_fed_back_in_the_source_convention(tmp_path) -> None:
    conv = ActionConverter(ActionSpec(scale=0.5, default_pose=[0.0] * 12),
                           np.array([JOINT_NAMES.index(n) for n in ODD_ORDER]), 0.25)
    # msta action 0 = msta default pose; source action = (default[perm] - 0) / 0.5
    src = conv.to_source(np.zeros((1, 12)))
    np.testing.assert_allclose(src[0, :3], [-0.2, 2.0, -3.0])   # RR: -0.1, 1.0, -1.5
    np.testing.assert_allclose(src[0, 3:6], [0.2, 1.6, -3.0])   # FL: 0.1, 0.8, -1.5
    # a source that echoes its last action gives msta's last action back
    echo = build(tmp_path, select(12, list(range(12))), "onnx", [{"name": "last_action"}], 12,
                 joint_order=ODD_ORDER, action={"scale": 0.5, "default_pose": [0.0] * 12})
    obs = random_obs(4, seed=3)
    np.testing.assert_allclose(echo.act(obs), obs["last_action"], rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("layout", ["frame", "signal"])
def test_history_stacking_and_reset(tmp_path, layout) -> None:
    # two signals of 3 channels, 2 frames -> 12 inputs echoed to the 12 outputs
    t = build(tmp_path, select(12, list(range(12))), "torchscript",
              [{"name": "command"}, {"name": "gravity"}], 12, history=2,
              history_layout=layout)
    obs = [random_obs(2, seed=s) for s in range(4)]

    def expected(old: dict, new: dict) -> np.ndarray:
        if layout == "frame":
            parts = [old["command"], old["gravity"], new["command"], new["gravity"]]
        else:
            parts = [old["command"], new["command"], old["gravity"], new["gravity"]]
        return np.concatenate(parts, axis=1)

    np.testing.assert_allclose(t.act(obs[0]), expected(obs[0], obs[0]), atol=1e-6)  # repeated
    np.testing.assert_allclose(t.act(obs[1]), expected(obs[0], obs[1]), atol=1e-6)
    t.reset(np.array([1]))
    a = t.act(obs[2])
    np.testing.assert_allclose(a[0], expected(obs[1], obs[2])[0], atol=1e-6)
    np.testing.assert_allclose(a[1], expected(obs[2], obs[2])[1], atol=1e-6)


@pytest.mark.parametrize("fmt", FORMATS)
def test_input_size_mismatch_names_both_sizes_and_the_file(tmp_path, fmt) -> None:
    model = export(mlp(10), 10, fmt, tmp_path / "small")
    spec = write_spec(tmp_path, model, [{"name": "command"}, {"name": "gravity"}], history=1)
    with pytest.raises(ValueError, match=rf"6 inputs.*{model.name}.*expects 10"):
        ImportedTeacher.from_spec(spec)


@pytest.mark.parametrize("fmt", FORMATS)
def test_output_size_mismatch(tmp_path, fmt) -> None:
    model = export(mlp(3, out_dim=8), 3, fmt, tmp_path / "eight")
    with pytest.raises(ValueError, match=r"returns shape \(8,\)"):
        ImportedTeacher.from_spec(write_spec(tmp_path, model, [{"name": "command"}]))


def test_spec_errors(tmp_path) -> None:
    model = export(mlp(3), 3, "torchscript", tmp_path / "m")
    cases = [
        ({"inputs": [{"name": "command", "bogus": 1}]}, "bogus"),
        ({"inputs": [{"name": "command", "scale": [1.0, 2.0]}]}, "command.*2 values"),
        ({"inputs": [{"name": "nope"}]}, "nope"),
        ({"inputs": [{"name": "command"}], "joint_order": JOINT_NAMES[:11]}, "joint_order"),
        ({"inputs": [{"name": "command"}], "action": {"default_pose": [0.0]}}, "default_pose"),
        ({"inputs": [{"name": "command"}], "history": 0}, "history"),
    ]
    for extra, match in cases:
        spec = tmp_path / "s.json"
        spec.write_text(json.dumps({"model": model.name, **extra}))
        with pytest.raises((ValueError, KeyError), match=match):
            ImportedTeacher.from_spec(spec)
    spec.write_text(json.dumps({"model": "missing.pt", "inputs": [{"name": "command"}]}))
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        ImportedTeacher.from_spec(spec)


def test_yaml_spec_and_registry(tmp_path) -> None:
    net = mlp(3)
    model = export(net, 3, "torchscript", tmp_path / "y")
    spec = tmp_path / "teacher.yaml"
    spec.write_text(f"model: {model.name}\ninputs:\n  - name: command\n    scale: [2.0, 2.0, 0.25]\n")
    t = make_teacher("imported", spec=spec)
    obs = random_obs(2)
    with torch.no_grad():
        want = net(torch.tensor(obs["command"] * np.array([2.0, 2.0, 0.25]),
                                dtype=torch.float32)).numpy()
    np.testing.assert_allclose(t.act(obs), want, rtol=1e-5, atol=1e-6)


def test_drives_the_real_env(tmp_path) -> None:
    inputs = [{"name": n} for n in STUDENT_SENSORS]
    t = build(tmp_path, mlp(98), "onnx", inputs, 98, history=2)
    env = QuadrupedEnv(EnvConfig(num_envs=3, nthread=1, seed=2))
    obs = env.reset()
    for _ in range(5):
        a = t.act(obs)
        assert a.shape == (3, 12) and np.all(np.isfinite(a))
        res = env.step(a)
        obs = res.obs
        t.reset(np.flatnonzero(res.done))

"""The student base (issue 16): the shared config fields and their checks, the processor
base, the transformer module MSTA and TERT share, one registration per policy, and
checkpoints saved before this design still loading bit for bit."""

from __future__ import annotations

import ast
import json
from dataclasses import dataclass, fields
from pathlib import Path

import pytest
import torch
from torch import Tensor, nn

import msta.policies.baselines
from msta.data import sensors
from msta.data.cli import args_doc
from msta.data.robot import NUM_JOINTS
from msta.policies.baselines import TimestepPolicy, TimestepProcessor
from msta.policies.config import PolicyConfig
from msta.policies.factory import load_policy, make_policy
from msta.policies.input_spec import InputSpec
from msta.policies.processor import StudentProcessor
from msta.policies.registry import (
    get_config_class,
    get_policy_class,
    make_config,
    policy_kind,
    register_policy,
    registered_policies,
    unregister_policy,
)
from msta.policies.transformer import Block

REPO = Path(__file__).resolve().parents[2]
FIXTURES = Path(__file__).parent / "fixtures" / "before_student_base"
#: the sensors of the fixture checkpoints
FIXTURE_SENSORS = ("command", "gravity", "foot_contact", "last_action")
SHARED = ("input_sensors", "history", "clip_std", "mask_ratio", "head_hidden_dim",
          "action_key", "action_dim", "normalize_action")

pytestmark = pytest.mark.usefixtures("one_thread")


def fixture_batch() -> dict[str, Tensor]:
    """The batch the fixture checkpoints acted on when they were written."""
    g = torch.Generator().manual_seed(0)
    batch = {n: torch.randn(3, 4, sensors.get(n).dim, generator=g) for n in FIXTURE_SENSORS}
    batch["foot_contact"] = (batch["foot_contact"] > 0).float()
    pad = torch.zeros(3, 4, dtype=torch.bool)
    pad[1, :2] = True
    batch["pad"] = pad
    return batch


def stats() -> dict[str, dict[str, list[float]]]:
    out = {sensors.get(n).column: {"mean": [0.0] * sensors.get(n).dim,
                                   "std": [1.0] * sensors.get(n).dim}
           for n in sensors.STUDENT_SENSORS if not sensors.get(n).binary}
    out["action"] = {"mean": [0.0] * NUM_JOINTS, "std": [1.0] * NUM_JOINTS}
    return out


# --- checkpoints written before the refactor ----------------------------------------------
@pytest.mark.parametrize("name", ["msta", "tert_separate", "gru"])
def test_checkpoints_saved_before_the_student_base_act_the_same(name: str) -> None:
    expected = json.loads((FIXTURES / "expected_actions.json").read_text())[name]
    policy = load_policy(FIXTURES / name)
    assert policy.config.type == name and policy.config.input_sensors == FIXTURE_SENSORS
    out = policy.act(fixture_batch(), generator=torch.Generator().manual_seed(1))
    # same numbers up to float rounding: MSTA's last block now computes only <S>'s row
    # (the same sums in another order), so bit equality is not promised, 1e-6 is
    torch.testing.assert_close(out, torch.tensor(expected, dtype=torch.float32),
                               atol=1e-6, rtol=0)


# --- the shared config --------------------------------------------------------------------
@pytest.mark.parametrize("name", registered_policies())
def test_every_student_config_declares_and_checks_the_shared_fields(name: str) -> None:
    cls = get_config_class(name)
    assert issubclass(cls, PolicyConfig)
    names = [f.name for f in fields(cls)]
    assert set(SHARED) <= set(names)
    docs = args_doc(cls)
    assert all(docs.get(n) for n in names), [n for n in names if not docs.get(n)]
    cfg = make_config(name)
    assert cfg.action_dim == NUM_JOINTS and cfg.history == 15 and cfg.action_key == "action"
    for bad, message in [({"mask_ratio": 1.0}, r"mask_ratio must be in \[0, 1\)"),
                         ({"mask_ratio": -0.1}, r"mask_ratio must be in \[0, 1\)"),
                         ({"history": 0}, "history must be > 0"),
                         ({"head_hidden_dim": -1}, "head_hidden_dim must be >= 0"),
                         ({"input_sensors": ()}, "input_sensors is empty"),
                         ({"input_sensors": ("command", "command")}, "duplicates"),
                         ({"input_sensors": (sensors.PRIVILEGED_SENSORS[0],)}, "privileged")]:
        with pytest.raises(ValueError, match=message):
            make_config(name, **bad)
    with pytest.raises(KeyError, match=f"unknown {name} preset 'huge'; known presets"):
        cls.from_preset("huge")
    assert set(cls.PRESETS) >= {"paper", "cpu", "tiny"}


# --- shared processor and transformer -----------------------------------------------------
def test_students_build_on_the_shared_processor_and_transformer() -> None:
    for name in registered_policies():
        assert issubclass(get_policy_class(name).processor_class, StudentProcessor), name
    torch.manual_seed(0)
    msta = make_policy(make_config("msta", dim=32, num_heads=2, num_layers=1), stats())
    tert = make_policy(make_config("tert_concat", dim=32, num_heads=2, num_layers=1), stats())
    assert type(msta.model.blocks[0]) is Block and type(tert.blocks[0]) is Block
    # the state-dict names of saved checkpoints are the shared block's
    assert {"model.blocks.0.attn.qkv.weight", "model.blocks.0.mlp.2.weight"} <= set(msta.state_dict())
    assert {"blocks.0.attn.qkv.weight", "blocks.0.mlp.2.weight"} <= set(tert.state_dict())


def test_no_baseline_imports_msta() -> None:
    bad = []
    for path in sorted((REPO / "policies" / "baselines").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            bad += [f"{path.name}: {n}" for n in names if n.startswith("msta.policies.msta")]
    assert bad == []


def test_the_action_size_is_the_robots_joint_count() -> None:
    assert sensors.ACTION_DIM == NUM_JOINTS == 12
    InputSpec(dead_joints=(NUM_JOINTS - 1,))
    with pytest.raises(ValueError, match=f"out of range \\[0, {NUM_JOINTS}\\)"):
        InputSpec(dead_joints=(NUM_JOINTS,))


# --- one registration ---------------------------------------------------------------------
@dataclass
class NewestStepConfig(PolicyConfig):
    """A linear map of the newest step (a policy defined by a test).

    Args:
        gain: factor on the output.
    """

    gain: float = 1.0


class NewestStepPolicy(TimestepPolicy):
    """Linear in the newest step's input vector."""

    config_class = NewestStepConfig

    def __init__(self, config: NewestStepConfig, processor: TimestepProcessor) -> None:
        super().__init__(config, processor)
        self.lin = nn.Linear(self.num_inputs, config.action_dim)

    def encode(self, x: Tensor, pad: Tensor | None) -> Tensor:
        return self.config.gain * self.lin(x[:, -1])  # (B, A)


@pytest.fixture
def registered_newest_step():
    register_policy("test_newest_step", kind="baseline")(NewestStepPolicy)
    yield "test_newest_step"
    unregister_policy("test_newest_step")


def test_one_registration_adds_a_policy_everywhere(registered_newest_step, tmp_path, capsys):
    name = registered_newest_step
    assert name in registered_policies() and name in registered_policies("baseline")
    assert name not in registered_policies("reference") and policy_kind(name) == "baseline"
    assert name in msta.policies.baselines.BASELINES
    assert name in PolicyConfig.get_known_choices()
    cfg = make_config(name, gain=2.0, history=3)
    assert cfg.type == name and cfg.mask_ratio == 0.0
    torch.manual_seed(0)
    policy = make_policy(cfg, stats())
    batch = {n: torch.randn(2, 3, sensors.get(n).dim) for n in cfg.input_sensors}
    policy.save_pretrained(tmp_path / "ckpt")
    loaded = load_policy(tmp_path / "ckpt")
    assert type(loaded) is NewestStepPolicy and loaded.config == cfg
    assert torch.equal(loaded.act(batch), policy.act(batch))

    from msta.train.offline import main

    with pytest.raises(SystemExit):
        main([f"--policy.type={name}", "--help"])
    assert name in capsys.readouterr().out


def test_unregister_only_removes_what_a_test_added(registered_newest_step) -> None:
    with pytest.raises(ValueError, match="built-in"):
        unregister_policy("msta")
    with pytest.raises(KeyError):
        unregister_policy("no_such_policy")
    with pytest.raises(ValueError, match="kind"):
        register_policy("x", kind="teacher")
    with pytest.raises(ValueError, match="already registered"):
        register_policy("msta")(NewestStepPolicy)

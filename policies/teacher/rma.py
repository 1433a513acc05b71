"""The paper's RMA-style privileged teacher: factor encoder + policy MLP.

    l_t = mu(e_t)               mu: MLP encoder_hidden (512, 256, 128) -> latent_dim
    a_t = pi(l_t, o_t)          pi: MLP policy_hidden (256, 128) -> 12

e_t is the concatenation of the scaled privileged signals, o_t of the scaled
proprioceptive signals (by default the student's 49 scalars). Hidden layers use ELU as
in RMA / legged_gym. Scaling is part of the config (``SignalSpec``:
``clip((x - offset) * scale)``), so a checkpoint carries everything needed to run it.
Defaults follow legged_gym's observation scales (see docs/teachers.md).

Checkpoint: ``<dir>/config.json`` (``{"type": "rma", ...}``) and
``<dir>/model.safetensors``. Training by PPO is separate work; the teacher is usable
wherever a teacher is (randomly initialised weights included).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from itertools import pairwise
from pathlib import Path
from typing import Any

import draccus
import numpy as np
import torch
from safetensors.torch import load_file, save_file
from torch import Tensor, nn

from msta.data.robot import A1, RobotDescription
from msta.data.sensors import ACTION_DIM
from msta.policies.teacher.base import check_obs, register_teacher, teacher_view
from msta.policies.teacher.imported import InputScaler, SignalSpec

CONFIG_NAME = "config.json"
WEIGHTS_NAME = "model.safetensors"
TYPE = "rma"

ACTIVATIONS: dict[str, type[nn.Module]] = {
    "elu": nn.ELU, "relu": nn.ReLU, "tanh": nn.Tanh, "silu": nn.SiLU,
}

# Dynamics channels: friction, added_mass, com_x/y/z, motor_strength, kp_factor, kd_factor.
# Offsets at the centre and scales mapping the default randomization ranges to about [-1, 1].
_DYN_OFFSET = [0.875, 0.5, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0]
_DYN_SCALE = [2.667, 0.667, 20.0, 20.0, 20.0, 10.0, 10.0, 10.0]


def default_privileged() -> list[SignalSpec]:
    """e_t: base velocity (legged_gym scales 2.0 / 0.25), orientation, height scan
    (relative to a 0.3 m nominal height, x5, clipped at +-5), dynamics (centred)."""
    return [
        SignalSpec("base_lin_vel", scale=2.0),
        SignalSpec("base_ang_vel", scale=0.25),
        SignalSpec("orientation"),
        SignalSpec("height_scan", scale=5.0, offset=-0.3, clip=5.0),
        SignalSpec("dynamics", scale=list(_DYN_SCALE), offset=list(_DYN_OFFSET)),
    ]


def default_proprio(robot: RobotDescription = A1) -> list[SignalSpec]:
    """o_t: the student's 49 scalars with legged_gym scales (joint_pos minus the robot's
    default pose, joint_vel x0.05, ang_vel x0.25, command x(2, 2, 0.25)).

    Args:
        robot: the robot the teacher is for (its ``default_pose``; default the A1).
    """
    return [
        SignalSpec("joint_pos", offset=[float(v) for v in robot.default_pose]),
        SignalSpec("joint_vel", scale=0.05),
        SignalSpec("ang_vel", scale=0.25),
        SignalSpec("gravity"),
        SignalSpec("foot_contact"),
        SignalSpec("command", scale=[2.0, 2.0, 0.25]),
        SignalSpec("last_action"),
    ]


@dataclass
class RMAConfig:
    """RMA teacher architecture and input scaling.

    Args:
        privileged: signals of e_t, in order (privileged registry sensors by default).
        proprio: signals of o_t, in order (the 49 student scalars by default, joint angles
            relative to the A1's default pose; :meth:`for_robot`: another robot's).
        encoder_hidden: hidden widths of the factor encoder mu (paper: 512, 256, 128).
        latent_dim: width of l_t (not stated in the paper; RMA used 8 for 17 factors, we
            encode 205 privileged values incl. a 187-point height scan).
        policy_hidden: hidden widths of the policy pi (paper: 256, 128).
        activation: hidden activation, a key of ``ACTIVATIONS``.
    """

    privileged: list[SignalSpec] = field(default_factory=default_privileged)
    proprio: list[SignalSpec] = field(default_factory=default_proprio)
    encoder_hidden: tuple[int, ...] = (512, 256, 128)
    latent_dim: int = 32
    policy_hidden: tuple[int, ...] = (256, 128)
    activation: str = "elu"

    def __post_init__(self) -> None:
        self.encoder_hidden = tuple(self.encoder_hidden)
        self.policy_hidden = tuple(self.policy_hidden)
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"activation {self.activation!r} unknown; known: {sorted(ACTIVATIONS)}")
        for what in ("encoder_hidden", "policy_hidden"):
            if any(w < 1 for w in getattr(self, what)):
                raise ValueError(f"{what}={getattr(self, what)} widths must be >= 1")
        if self.latent_dim < 1:
            raise ValueError(f"latent_dim={self.latent_dim} must be >= 1")
        # validates names, per-channel lengths and duplicates
        InputScaler(self.privileged)
        InputScaler(self.proprio)

    @classmethod
    def for_robot(cls, robot: RobotDescription, **overrides: Any) -> RMAConfig:
        """The default config of a new teacher for ``robot``: its joint angles read relative
        to that robot's default pose (the A1: ``RMAConfig()``).

        Args:
            robot: the simulated robot's description.
            overrides: other fields of the config.
        """
        return cls(proprio=default_proprio(robot), **overrides)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict with ``"type": "rma"``."""
        return {"type": TYPE, **draccus.encode(self)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RMAConfig:
        """Build from a dict (``type`` optional, must be ``rma``); unknown keys raise.

        Args:
            data: e.g. the content of config.json.
        """
        data = dict(data)
        kind = data.pop("type", TYPE)
        if kind != TYPE:
            raise ValueError(f"config type {kind!r} is not an RMA teacher ({TYPE!r})")
        try:
            return draccus.decode(cls, data)
        except (draccus.utils.DecodingError, draccus.utils.ParsingError) as e:
            raise ValueError(f"invalid RMA teacher config: {e.__cause__ or e}") from None


def mlp(sizes: list[int], activation: str) -> nn.Sequential:
    """Linear layers through ``sizes`` with the activation between them (none at the end)."""
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(pairwise(sizes)):
        layers.append(nn.Linear(a, b))
        if i < len(sizes) - 2:
            layers.append(ACTIVATIONS[activation]())
    return nn.Sequential(*layers)


def check_pose(config: RMAConfig, robot: RobotDescription, source: str) -> None:
    """A one-line error when ``config`` reads joint angles about another default pose than
    ``robot``'s: a teacher trained on another robot (the A1's shipped ones on the Go1)."""
    pose = next((s.offset for s in config.proprio if s.name == "joint_pos"), None)
    if isinstance(pose, list | tuple) and not np.allclose(pose, robot.default_pose, atol=1e-6):
        raise ValueError(f"the rma teacher {source} reads joint angles about the default pose "
                         f"{[round(float(v), 3) for v in pose]}, not robot {robot.name!r}'s "
                         f"{list(robot.default_pose)}: it was trained on another robot; give "
                         f"{robot.name}'s own (one msta-train-teacher trained on it)")


@register_teacher(TYPE)
class RMATeacher(nn.Module):
    """RMA teacher: a torch module (``forward`` on scaled tensors) and a Teacher
    (``act`` on registry-keyed numpy observations).

    Args:
        config: architecture and scaling; default ``RMAConfig()``. Exclusive with
            ``pretrained``.
        pretrained: a directory written by :meth:`save_pretrained` to load.
        device: torch device for inference.
        robot: the simulated robot (None: the A1). The network's inputs and their scaling
            are its config's (the shipped checkpoints' are the A1's); on a robot without
            ``foot_contact`` it reads the simulator's ``true_contact`` (:func:`teacher_view`).
    """

    name = TYPE

    def __init__(self, config: RMAConfig | None = None, pretrained: str | Path | None = None,
                 device: str | torch.device = "cpu",
                 robot: RobotDescription | None = None) -> None:
        super().__init__()
        state = None
        if pretrained is not None:
            if config is not None:
                raise ValueError("pass either config or pretrained, not both")
            config, state = _read_checkpoint(Path(pretrained))
        self.config = config = config or RMAConfig()
        if robot is not None:
            check_pose(config, robot, str(pretrained or "config"))
        self.priv_in = InputScaler(config.privileged)
        self.proprio_in = InputScaler(config.proprio)
        self.encoder = mlp([self.priv_in.dim, *config.encoder_hidden, config.latent_dim],
                           config.activation)
        self.policy = mlp([config.latent_dim + self.proprio_in.dim, *config.policy_hidden,
                           ACTION_DIM], config.activation)
        if state is not None:
            try:
                self.load_state_dict(state, strict=True)
            except RuntimeError as e:
                raise ValueError(f"weights in {pretrained} do not match its config: {e}") from None
        self.sensors: tuple[str, ...] = tuple(
            dict.fromkeys(self.priv_in.names + self.proprio_in.names))
        self.device = torch.device(device)
        self.to(self.device).eval()

    def forward(self, privileged: Tensor, proprio: Tensor) -> Tensor:
        """Scaled inputs -> actions.

        Args:
            privileged: (B, P) scaled e_t.
            proprio: (B, O) scaled o_t.
        """
        latent = self.encoder(privileged)                          # (B, latent_dim)
        return self.policy(torch.cat([latent, proprio], dim=-1))   # (B, 12)

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """(N, 12) float32 actions for registry-keyed (N, dim) observations.

        Args:
            obs: holds at least ``self.sensors`` (``foot_contact`` or its privileged copy).
        """
        obs = teacher_view(obs)
        check_obs(self, obs)
        priv = torch.from_numpy(self.priv_in(obs)).to(self.device)
        prop = torch.from_numpy(self.proprio_in(obs)).to(self.device)
        with torch.no_grad():
            out = self(priv, prop)
        return out.cpu().numpy().astype(np.float32)

    def reset(self, ids: np.ndarray) -> None:
        """Stateless: nothing to clear."""

    def save_pretrained(self, directory: str | Path) -> Path:
        """Write config.json and model.safetensors into ``directory`` (created if missing).

        Args:
            directory: output directory.
        """
        out = Path(directory)
        out.mkdir(parents=True, exist_ok=True)
        (out / CONFIG_NAME).write_text(json.dumps(self.config.to_dict(), indent=2) + "\n")
        state = {k: v.detach().contiguous().cpu() for k, v in self.state_dict().items()}
        save_file(state, str(out / WEIGHTS_NAME), metadata={"type": TYPE})
        return out

    @classmethod
    def from_pretrained(cls, directory: str | Path,
                        device: str | torch.device = "cpu") -> RMATeacher:
        """Load a checkpoint written by :meth:`save_pretrained`.

        Args:
            directory: checkpoint directory.
            device: torch device for inference.
        """
        return cls(pretrained=directory, device=device)


def _read_checkpoint(directory: Path) -> tuple[RMAConfig, dict[str, Tensor]]:
    cfg_path, w_path = directory / CONFIG_NAME, directory / WEIGHTS_NAME
    for p in (cfg_path, w_path):
        if not p.is_file():
            raise FileNotFoundError(f"RMA teacher checkpoint {str(directory)!r} has no {p.name}")
    try:
        data = json.loads(cfg_path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{str(cfg_path)!r} is not valid JSON: {e}") from None
    return RMAConfig.from_dict(data), load_file(str(w_path))

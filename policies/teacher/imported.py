"""Teachers trained elsewhere: a TorchScript or ONNX file plus a spec file.

The spec (JSON, or YAML with a ``.yaml``/``.yml`` suffix; see docs/teachers.md) says which
registry signals the network reads and in what order (its input vector is their
concatenation), the per-signal ``input = clip((x - offset) * scale)``, an optional frame
history, the source's joint order and its action convention. The teacher converts msta's
observations into the source's input and the source's output into msta's action:

    source target  = source_default + source_scale * clip(out)          (source joint order)
    msta action    = (target - msta_default) / msta_action_scale        (msta joint order)

``last_action`` inputs are mapped the other way (msta action -> source action, source
order), so a network that was fed its own previous output sees the same numbers here.

This module also holds :class:`SignalSpec` / :class:`InputScaler`, the per-signal scaling
shared with the RMA teacher.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Protocol

import draccus
import numpy as np
import torch

from msta.data.robot import A1, DEFAULT_POSE, RobotDescription
from msta.data.sensors import ACTION_DIM, FOOT_NAMES, JOINT_NAMES, LEGS, get
from msta.policies.teacher.base import check_obs, register_teacher, teacher_view

Scalar = float | list[float]


@dataclass
class SignalSpec:
    """One input signal: ``clip((x - offset) * scale, -clip, clip)``.

    Args:
        name: registry sensor name (msta_data/sensors.py).
        scale: a scalar or one value per channel.
        offset: a scalar or one value per channel (subtracted before scaling).
        clip: symmetric clip applied after scaling; ``None`` = no clip.
    """

    name: str
    scale: Scalar = 1.0
    offset: Scalar = 0.0
    clip: float | None = None

    @property
    def dim(self) -> int:
        return get(self.name).dim

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(offset, scale) as float64 arrays of shape (dim,); raises on a bad length."""
        out = []
        for what in ("offset", "scale"):
            v = np.atleast_1d(np.asarray(getattr(self, what), dtype=np.float64))
            if v.ndim != 1 or len(v) not in (1, self.dim):
                raise ValueError(f"signal {self.name!r}: {what} has {v.size} values, expected 1 "
                                 f"or {self.dim} (one per channel)")
            if not np.all(np.isfinite(v)):
                raise ValueError(f"signal {self.name!r}: {what} {v.tolist()} is not finite")
            out.append(np.broadcast_to(v, (self.dim,)).copy())
        if self.clip is not None and not self.clip > 0:
            raise ValueError(f"signal {self.name!r}: clip={self.clip} must be > 0 or null")
        return out[0], out[1]


class InputScaler:
    """Concatenate scaled registry signals into one (N, D) float32 vector.

    It reads the observation as a teacher does (:func:`teacher_view`): on a robot without
    ``foot_contact`` that input is the simulator's ``true_contact``, so every path that
    builds a teacher's inputs from simulator observations (acting, the warm start,
    ``RslVecEnv``'s groups) sees the same numbers.

    Args:
        signals: the signals, in input order.
    """

    def __init__(self, signals: list[SignalSpec]) -> None:
        if not signals:
            raise ValueError("at least one input signal is needed")
        names = [s.name for s in signals]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"input signals {dup} are listed more than once")
        self.signals = list(signals)
        offs, scales = zip(*(s.arrays() for s in signals))
        self.offset = np.concatenate(offs)            # (D,)
        self.scale = np.concatenate(scales)           # (D,)
        clips = [np.full(s.dim, np.inf if s.clip is None else s.clip) for s in signals]
        self.clip = np.concatenate(clips)             # (D,)
        self.dims = [s.dim for s in signals]
        self.dim = int(sum(self.dims))

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.signals)

    def __call__(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """(N, D) float32 from registry-keyed (N, dim) arrays, read through :func:`teacher_view`."""
        obs = teacher_view(obs)
        x = np.concatenate([np.asarray(obs[n], dtype=np.float64) for n in self.names], axis=1)
        x = np.clip((x - self.offset) * self.scale, -self.clip, self.clip)
        return x.astype(np.float32)


@dataclass
class ActionSpec:
    """The source's action convention (values in the source's joint order).

    Args:
        scale: source action scale (scalar or 12 values): target = default + scale * out.
        default_pose: the source's default joint positions (12, rad); ``None`` = msta's
            default pose (in the source's joint order).
        clip: clip the raw network output to +-clip before scaling; ``None`` = no clip.
    """

    scale: Scalar = 0.25
    default_pose: list[float] | None = None
    clip: float | None = None


@dataclass
class ImportedSpec:
    """Spec file of an imported teacher.

    Args:
        model: path of the .pt (TorchScript) or .onnx file, relative to the spec file.
        format: ``torchscript``, ``onnx`` or ``auto`` (from the suffix: .onnx -> onnx,
            anything else -> torchscript).
        inputs: the signals the network reads, in order; their concatenation is one frame.
        history: frames stacked per input (oldest first); 1 = no history.
        history_layout: ``frame``: [frame_t-k+1, ..., frame_t] (legged_gym style);
            ``signal``: each signal's k frames together, signals in order (Isaac Lab
            observation-term history).
        joint_order: the source's joint order as msta joint names (e.g. FR_hip, FR_thigh,
            ...); ``None`` = msta's order (FL, FR, RL, RR). Per-joint signals (joint_pos,
            joint_vel, last_action) and per-foot signals (foot_contact, in the order legs
            first appear here) are permuted into it; the output is permuted back.
        action: the source's action convention.
    """

    model: str = ""
    format: Literal["auto", "torchscript", "onnx"] = "auto"
    inputs: list[SignalSpec] = field(default_factory=list)
    history: int = 1
    history_layout: Literal["frame", "signal"] = "frame"
    joint_order: list[str] | None = None
    action: ActionSpec = field(default_factory=ActionSpec)


def load_spec(path: str | Path) -> ImportedSpec:
    """Read and type-check a spec file (.json, .yaml or .yml); unknown keys are errors.

    Args:
        path: the spec file.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"imported-teacher spec {str(path)!r} does not exist")
    text = path.read_text()
    if path.suffix == ".json":
        data = json.loads(text)
    elif path.suffix in (".yaml", ".yml"):
        import yaml  # lazy: yaml only for a .yaml spec file

        data = yaml.safe_load(text)
    else:
        raise ValueError(f"spec {str(path)!r}: unknown suffix {path.suffix!r} "
                         f"(use .json, .yaml or .yml)")
    if not isinstance(data, dict):
        raise TypeError(f"spec {str(path)!r} must hold a mapping, got {type(data).__name__}")
    try:
        return draccus.decode(ImportedSpec, data)
    except (draccus.utils.DecodingError, draccus.utils.ParsingError) as e:
        raise ValueError(f"invalid imported-teacher spec {str(path)!r}: {e.__cause__ or e}"
                         ) from None


# ---------------------------------------------------------------------- backends
class Backend(Protocol):
    """A loaded network: (N, D) float32 -> (N, out) float32."""

    #: input width declared by the file (None when the format does not say)
    declared_dim: int | None

    def __call__(self, x: np.ndarray) -> np.ndarray: ...


class TorchScriptBackend:
    """A ``torch.jit.save``'d module."""

    def __init__(self, path: Path, device: str) -> None:
        self.device = torch.device(device)
        self.module = torch.jit.load(str(path), map_location=self.device).eval()
        mats = [p for p in self.module.parameters() if p.ndim == 2]
        # best effort: the first weight matrix of an MLP is (hidden, input width)
        self.declared_dim = int(mats[0].shape[1]) if mats else None

    def __call__(self, x: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            out = self.module(torch.from_numpy(x).to(self.device))
        return out.detach().cpu().numpy().astype(np.float32)


class OnnxBackend:
    """An ONNX file run by onnxruntime (CPU)."""

    def __init__(self, path: Path, device: str) -> None:
        try:
            import onnxruntime as ort  # lazy: onnxruntime loads only where an ONNX graph runs
        except ImportError as e:
            raise ImportError(f"running the ONNX teacher {str(path)!r} needs onnxruntime "
                              f"(pip install onnxruntime): {e}") from e
        if device != "cpu":
            raise ValueError(f"ONNX teachers run on the CPU; got device={device!r}")
        opts = ort.SessionOptions()
        opts.log_severity_level = 3
        self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        ins = self.session.get_inputs()
        if len(ins) != 1:
            raise ValueError(f"ONNX teacher {str(path)!r} has {len(ins)} inputs "
                             f"({[i.name for i in ins]}); exactly one is supported")
        self.input_name = ins[0].name
        shape = ins[0].shape
        if len(shape) != 2:
            raise ValueError(f"ONNX teacher {str(path)!r}: input {self.input_name!r} has shape "
                             f"{shape}, expected (batch, features)")
        self.declared_dim = shape[1] if isinstance(shape[1], int) else None

    def __call__(self, x: np.ndarray) -> np.ndarray:
        out = self.session.run(None, {self.input_name: x})[0]
        return np.asarray(out, dtype=np.float32)


BACKENDS: dict[str, Callable[[Path, str], Backend]] = {
    "torchscript": TorchScriptBackend,
    "onnx": OnnxBackend,
}


def _format_of(spec: ImportedSpec, path: Path) -> str:
    if spec.format != "auto":
        return spec.format
    return "onnx" if path.suffix.lower() == ".onnx" else "torchscript"


def _check_io(backend: Backend, dim: int, path: Path, spec_what: str) -> None:
    """Raise a clear error when the file's input or output size disagrees with the spec."""
    if backend.declared_dim is not None and backend.declared_dim != dim:
        raise ValueError(f"input size mismatch: the spec gives {dim} inputs ({spec_what}) but "
                         f"{str(path)!r} expects {backend.declared_dim}")
    try:
        out = backend(np.zeros((2, dim), dtype=np.float32))
    except Exception as e:  # noqa: BLE001  (torch and onnxruntime raise their own types)
        raise ValueError(f"input size mismatch: the spec gives {dim} inputs ({spec_what}) but "
                         f"{str(path)!r} rejects a (2, {dim}) input "
                         f"(file expects {backend.declared_dim or 'an unknown size'}): "
                         f"{str(e).splitlines()[0] if str(e) else type(e).__name__}") from None
    if out.shape != (2, ACTION_DIM):
        raise ValueError(f"{str(path)!r} returns shape {tuple(out.shape)[1:]} per sample, "
                         f"expected ({ACTION_DIM},) joint actions")


# ---------------------------------------------------------------------- conventions
def joint_permutation(joint_order: list[str] | None) -> np.ndarray:
    """Indices ``perm`` with ``source_vec = msta_vec[..., perm]`` (identity when None).

    Args:
        joint_order: the source's joint order as msta joint names.
    """
    if joint_order is None:
        return np.arange(len(JOINT_NAMES))
    if sorted(joint_order) != sorted(JOINT_NAMES):
        raise ValueError(f"joint_order {joint_order} must list each of {list(JOINT_NAMES)} once")
    return np.array([JOINT_NAMES.index(n) for n in joint_order])


def foot_permutation(joint_perm: np.ndarray) -> np.ndarray:
    """Foot indices in the order legs first appear in the joint permutation."""
    legs = list(dict.fromkeys(JOINT_NAMES[i].split("_")[0] for i in joint_perm))
    return np.array([LEGS.index(leg) for leg in legs])


class ActionConverter:
    """Map actions between a source convention and msta's.

    Args:
        spec: the source's action convention (values in source joint order).
        joint_perm: ``source = msta[..., joint_perm]``.
        msta_action_scale: msta's action scale (joint target = default pose + scale * a).
        msta_default_pose: (12,) the simulated robot's default pose (msta order); also the
            source's when ``spec.default_pose`` is unset.
    """

    def __init__(self, spec: ActionSpec, joint_perm: np.ndarray, msta_action_scale: float,
                 msta_default_pose: np.ndarray = DEFAULT_POSE) -> None:
        self.perm = joint_perm
        self.pose = np.asarray(msta_default_pose, dtype=np.float64)
        self.inv = np.argsort(joint_perm)
        scale = np.atleast_1d(np.asarray(spec.scale, dtype=np.float64))
        if scale.ndim != 1 or len(scale) not in (1, ACTION_DIM) or not np.all(scale != 0):
            raise ValueError(f"action.scale {spec.scale} must be a non-zero scalar or "
                             f"{ACTION_DIM} non-zero values")
        self.scale = np.broadcast_to(scale, (ACTION_DIM,)).copy()
        if spec.default_pose is None:
            self.default = self.pose[joint_perm].copy()
        else:
            self.default = np.asarray(spec.default_pose, dtype=np.float64)
            if self.default.shape != (ACTION_DIM,):
                raise ValueError(f"action.default_pose has {self.default.size} values, "
                                 f"expected {ACTION_DIM}")
        if spec.clip is not None and not spec.clip > 0:
            raise ValueError(f"action.clip={spec.clip} must be > 0 or null")
        self.clip = np.inf if spec.clip is None else float(spec.clip)
        if not msta_action_scale > 0:
            raise ValueError(f"msta_action_scale={msta_action_scale} must be > 0")
        self.msta_scale = float(msta_action_scale)

    def to_msta(self, out: np.ndarray) -> np.ndarray:
        """(N, 12) raw source output (source order) -> (N, 12) msta actions."""
        target = self.default + self.scale * np.clip(out.astype(np.float64), -self.clip, self.clip)
        return ((target[:, self.inv] - self.pose) / self.msta_scale).astype(np.float32)

    def to_source(self, action: np.ndarray) -> np.ndarray:
        """(N, 12) msta actions -> (N, 12) source actions (source order), e.g. last_action."""
        target = (self.pose + self.msta_scale * action.astype(np.float64))[:, self.perm]
        return (target - self.default) / self.scale


# ---------------------------------------------------------------------- teacher
@register_teacher("imported")
class ImportedTeacher:
    """A teacher network from another framework (TorchScript or ONNX) plus its spec.

    Args:
        spec: spec file path, or an :class:`ImportedSpec` (its model path is then taken
            relative to ``base_dir``).
        device: torch device for TorchScript files (ONNX runs on the CPU).
        msta_action_scale: the simulator's ``control.action_scale`` (None: ``robot``'s).
        base_dir: directory relative model paths start from when ``spec`` is an object.
        robot: the simulated robot (its default pose and action scale; None: the A1).
    """

    name = "imported"

    def __init__(self, spec: str | Path | ImportedSpec, device: str = "cpu",
                 msta_action_scale: float | None = None,
                 base_dir: str | Path = ".", robot: RobotDescription | None = None) -> None:
        robot = robot or A1
        if not isinstance(spec, ImportedSpec):
            base_dir = Path(spec).parent
            spec = load_spec(spec)
        self.spec = spec
        if not spec.model:
            raise ValueError("imported-teacher spec has no 'model' file")
        if spec.history < 1:
            raise ValueError(f"history={spec.history} must be >= 1")
        self.path = Path(base_dir) / spec.model
        if not self.path.is_file():
            raise FileNotFoundError(f"imported-teacher model {str(self.path)!r} does not exist")
        self.scaler = InputScaler(spec.inputs)
        self.sensors = self.scaler.names
        self.joint_perm = joint_permutation(spec.joint_order)
        self.foot_perm = foot_permutation(self.joint_perm)
        self.actions = ActionConverter(
            spec.action, self.joint_perm,
            robot.action_scale if msta_action_scale is None else msta_action_scale,
            np.array(robot.default_pose, dtype=np.float64))
        self.input_dim = self.scaler.dim * spec.history
        self.backend = BACKENDS[_format_of(spec, self.path)](self.path, device)
        what = " + ".join(f"{s.name} {s.dim}" for s in spec.inputs)
        if spec.history > 1:
            what = f"({what}) x history {spec.history}"
        _check_io(self.backend, self.input_dim, self.path, what)
        self._buf: np.ndarray | None = None       # (N, history, D) scaled frames
        self._fresh = np.zeros(0, dtype=bool)     # (N,) fill the history on the next act

    @classmethod
    def from_spec(cls, path: str | Path, device: str = "cpu",
                  msta_action_scale: float | None = None,
                  robot: RobotDescription | None = None) -> ImportedTeacher:
        """Load the teacher a spec file describes.

        Args:
            path: the spec file (.json / .yaml / .yml).
            device: torch device for TorchScript files.
            msta_action_scale: the simulator's ``control.action_scale`` (None: ``robot``'s).
            robot: the simulated robot (None: the A1).
        """
        return cls(path, device=device, msta_action_scale=msta_action_scale, robot=robot)

    def _to_source(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Registry observations in the source's joint/foot order and action convention."""
        src = {}
        for name in self.sensors:
            x = obs[name]
            if name == "last_action":
                x = self.actions.to_source(x)
            elif get(name).names == JOINT_NAMES:
                x = x[:, self.joint_perm]
            elif get(name).names == FOOT_NAMES:
                x = x[:, self.foot_perm]
            src[name] = x
        return src

    def _stack(self, frame: np.ndarray) -> np.ndarray:
        """Push ``frame`` (N, D) into the per-env history; the network input (N, k*D)."""
        n, k = frame.shape[0], self.spec.history
        if self._buf is None or self._buf.shape[0] != n:
            self._buf = np.zeros((n, k, frame.shape[1]), dtype=np.float32)
            self._fresh = np.ones(n, dtype=bool)
        self._buf[:, :-1] = self._buf[:, 1:]
        self._buf[:, -1] = frame
        self._buf[self._fresh] = frame[self._fresh, None, :]   # new episodes: repeat frame
        self._fresh[:] = False
        if self.spec.history_layout == "frame":
            return self._buf.reshape(n, -1)
        parts = np.split(self._buf, np.cumsum(self.scaler.dims)[:-1], axis=2)
        return np.concatenate([p.reshape(n, -1) for p in parts], axis=1)

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """(N, 12) float32 msta actions for a batch of registry observations.

        Args:
            obs: registry-keyed (N, dim) arrays holding at least ``self.sensors`` (or, for
                ``foot_contact``, its privileged copy: :func:`teacher_view`).
        """
        obs = teacher_view(obs)
        check_obs(self, obs)
        x = self._stack(self.scaler(self._to_source(obs)))
        out = self.backend(np.ascontiguousarray(x))
        return self.actions.to_msta(out)

    def reset(self, ids: np.ndarray) -> None:
        """Environments ``ids`` start new episodes: their history restarts on the next act."""
        if self._buf is not None:
            self._fresh[np.asarray(ids)] = True

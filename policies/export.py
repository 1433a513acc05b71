"""Export a trained student for a robot: TorchScript and ONNX files, a JSON spec, a parity check.

``msta-export --policy=outputs/train/final --output_dir=outputs/export`` writes::

    <output_dir>/student.pt      TorchScript (torch.jit.trace of the eager model)
    <output_dir>/student.onnx    ONNX (opset 17), runs in onnxruntime without torch
    <output_dir>/spec.json       what a robot program needs: input order, shapes, units,
                                 the robot and its action convention, and the parity figures

The exported graph is the whole student: raw sensor windows in (one float32 tensor
``(B, T, dim)`` per sensor, oldest step first, in the spec's order), the action out
(``(B, 12)``, the simulator's action: joint targets are ``default_pose + action_scale *
action``). Normalization, binning and the action's un-normalization are inside, from the
processor's statistics; no masking (test-time masking is an experiment, not deployment).
The sensor subset and T are fixed at export time (``--sensors=minimized``: the paper's
minimized observation {command, joint_pos, gravity, last_action} at T = 7); the batch size
is free. The action convention's numbers (joint names, default pose, action scale, clip,
gains, control period) and spec.json's ``robot`` are the description's of the robot the
student was trained on (``PolicyConfig.robots``; ``--robot`` picks one of several, or gives
the spec file of a robot that is not shipped: :func:`spec_robot`). A window that starts
before the episode does is filled by repeating the first reading (what the dataset reader
does for padded steps).

The parity check runs at every export: eager model vs each exported file on recorded
dataset windows (``--dataset``, default: the dataset the checkpoint was trained on when its
train_config.json names one that exists here) and on random windows drawn from the
statistics; the largest |action difference| is printed, stored in spec.json, and above
``--tolerance`` (default 1e-5, fp32) the export fails.

The Python checks of the eager path (NaN inputs, shapes) are not part of the graph: a
robot program checks its readings itself (the runtime in :mod:`msta.policies.onnx_runtime` does).

A checkpoint with a sensor guard (``guard.json`` + ``guard.safetensors``, ``msta-guard fit``)
exports with it: the two files are copied next to the student, spec.json's ``guard`` names
them, and the graph takes one more input per guarded sensor it reads, ``absent_<sensor>``
``(B, dim)`` bool over the sensor's channels (True = remove that channel from the window, as
``policy.act(absent=...)`` does; all False = the plain student). The robot loop runs the
guard (numpy, :mod:`msta.policies.guard`) on each observation and feeds its flags there. The
parity check then draws a random removal mask for every window (the first of each set
removes nothing). ``--absent_inputs`` asks for these inputs without a guard (a comma list
of sensors) or leaves them out (``none``); without a guard and the flag the export is as
before.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from msta.data import sensors as registry
from msta.data.robot import RobotDescription, load_robot, robot_names
from msta.policies.base import StudentPolicy
from msta.policies.config import check_trained_on
from msta.policies.export_files import (
    DEFAULT_TOLERANCE,
    FORMAT,
    FORMATS,
    ONNX_NAME,
    ONNX_OPSET,
    SPEC_NAME,
    TORCHSCRIPT_NAME,
    ExportParityError,
)
from msta.policies.export_removal import (
    ABSENT_PREFIX,
    absent_masks,
    removal_spec,
    trace_masks,
)
from msta.policies.input_spec import MINIMIZED_HISTORY, MINIMIZED_SENSORS

__all__ = [
    "ABSENT_PREFIX", "DEFAULT_TOLERANCE", "FORMAT", "DeployedStudent", "ExportParityError",
    "absent_masks", "export_student", "random_windows", "recorded_windows", "resolve_sensors",
    "spec_robot",
]


class DeployedStudent(nn.Module):
    """A student with its inputs fixed: ``forward(*windows) -> action (B, 12)``, raw units.

    Args:
        policy: any registered student (eval mode is set here).
        sensors: input sensors, in the order ``forward`` takes them (a subset of the
            policy's; the others are absent, as in the sensor-removal experiments).
        absent: sensors (of ``sensors``) whose per-sample channel removal ``forward`` takes
            after the windows: ``forward(*windows, *masks)``, each mask (B, dim) bool.
    """

    def __init__(self, policy: StudentPolicy, sensors: Sequence[str],
                 absent: Sequence[str] = ()) -> None:
        super().__init__()
        self.policy = policy.eval()
        # the wrapper too: torch.onnx.export restores the wrapper's own mode afterwards, and
        # a wrapper left in training mode would switch the policy to training with it
        self.eval()
        self.sensors = tuple(sensors)
        self.absent = tuple(absent)
        if self.absent:
            policy.check_absent()
        bad = [s for s in self.absent if s not in self.sensors]
        if bad or len(set(self.absent)) != len(self.absent):
            raise ValueError(f"absent inputs {bad} are not exported sensors {list(sensors)}")

    def forward(self, *inputs: Tensor) -> Tensor:
        n = len(self.sensors)
        batch = dict(zip(self.sensors, inputs[:n], strict=True))
        if self.absent:
            absent = dict(zip(self.absent, inputs[n:], strict=True))
            action = self.policy(batch, None, 0.0, None, absent=absent)  # (B, A), model space
        else:
            action = self.policy(batch, None, 0.0, None)  # (B, A), model space
        return self.policy.processor.unnormalize_action(action)  # (B, A), raw

    @property
    def input_names(self) -> list[str]:
        return [*self.sensors, *(ABSENT_PREFIX + s for s in self.absent)]


def resolve_sensors(policy: StudentPolicy, sensors: str | Sequence[str]) -> tuple[str, ...]:
    """``"all"``, ``"minimized"``, a comma list or a sequence -> the policy's sensors to export."""
    if isinstance(sensors, str):
        if sensors == "all":
            return tuple(policy.required_sensors)
        if sensors == "minimized":
            sensors = MINIMIZED_SENSORS
        else:
            sensors = [s.strip() for s in sensors.split(",") if s.strip()]
    chosen = tuple(sensors)
    for name in chosen:
        registry.get(name)  # KeyError naming the unknown sensor
        if name not in policy.required_sensors:
            raise ValueError(f"sensor {name!r} is not an input of this {policy.config.type} "
                             f"student (inputs: {', '.join(policy.required_sensors)})")
    if not chosen or len(set(chosen)) != len(chosen):
        raise ValueError(f"sensors must be distinct and non-empty, got {list(chosen)}")
    # the policy's own order: the spec lists inputs as the checkpoint does
    return tuple(n for n in policy.required_sensors if n in chosen)


def random_windows(policy: StudentPolicy, sensors: Sequence[str], T: int, n: int,
                   seed: int = 0) -> dict[str, np.ndarray]:
    """``n`` windows of raw readings drawn around the statistics (z ~ N(0, 1.5)); binary
    sensors 0/1. ``{sensor: (n, T, dim) float32}``."""
    rng = np.random.default_rng(seed)
    out = {}
    for name in sensors:
        spec = registry.get(name)
        if spec.binary:
            out[name] = rng.integers(0, 2, (n, T, spec.dim)).astype(np.float32)
            continue
        s = policy.processor.stats[spec.column]
        mean, std = np.asarray(s["mean"]), np.maximum(np.asarray(s["std"]), 1e-6)
        out[name] = (mean + std * 1.5 * rng.standard_normal((n, T, spec.dim))).astype(np.float32)
    return out


def recorded_windows(root: str | Path, sensors: Sequence[str], T: int, n: int
                     ) -> dict[str, np.ndarray]:
    """``n`` evenly spaced windows of a recorded dataset (padded steps repeat the episode's
    first reading, as a robot program fills its window). ``{sensor: (n, T, dim) float32}``."""
    # lazy: pandas (~0.3 s) only when the parity windows come from a dataset
    from msta.data.windows import WindowDataset

    ds = WindowDataset(root, sensors, T, extra_columns=(), verify="sizes")
    idx = np.linspace(0, len(ds) - 1, min(n, len(ds))).round().astype(np.int64)
    batch = ds.get_batch(idx)
    return {name: np.ascontiguousarray(batch[name], dtype=np.float32) for name in sensors}


def spec_robot(robots: Sequence[str], choice: str = "") -> RobotDescription:
    """The robot whose numbers spec.json's ``action_convention`` holds (msta-export's
    ``--robot``).

    Args:
        robots: the robots the student was trained on (``PolicyConfig.robots``).
        choice: a shipped robot's name or a spec file's path, one of ``robots``; empty: the
            one robot of ``robots``, which must then be a shipped robot.

    Raises:
        ValueError: (one line) several robots and no choice, a robot that is not shipped
            and no spec file given, or a choice the student was not trained on.
    """
    if choice:
        described = load_robot(choice)
        check_trained_on(tuple(robots), described.name, "the checkpoint", "--robot")
        return described
    if len(robots) > 1:
        raise ValueError(f"the checkpoint was trained on robots {', '.join(robots)}: pick the "
                         "one the export is for with --robot")
    if robots[0] not in robot_names():
        raise ValueError(f"the checkpoint was trained on robot {robots[0]!r}, which is not a "
                         f"shipped robot ({', '.join(robot_names())}): give its spec file "
                         "with --robot=<path>.toml")
    return load_robot(robots[0])


def export_student(
    policy: StudentPolicy,
    output_dir: str | Path,
    sensors: str | Sequence[str] = "all",
    history: int | None = None,
    formats: Sequence[str] = FORMATS,
    windows: Mapping[str, Mapping[str, np.ndarray]] | None = None,
    tolerance: float = DEFAULT_TOLERANCE,
    source: Mapping[str, Any] | None = None,
    absent: Sequence[str] = (),
    guard_dir: str | Path | None = None,
    robot: RobotDescription | None = None,
) -> dict[str, Any]:
    """Write the exported files and spec.json; return the spec.

    Args:
        policy: the student (moved to CPU, eval mode).
        output_dir: created if missing; files of the same names are replaced.
        sensors: ``"all"``, ``"minimized"``, a comma list or a sequence of names.
        history: window length T (None: the policy's training T, 7 for ``"minimized"``).
        formats: any of ``"torchscript"``, ``"onnx"``.
        windows: named sets of windows for the parity check, each ``{sensor: (n, T, dim)}``
            (None: 64 random windows).
        tolerance: largest allowed |exported - eager| action difference.
        source: provenance stored in the spec (checkpoint path, dataset, ...).
        absent: exported sensors that get an ``absent_<sensor>`` (B, dim) bool input (the
            per-sample channel removal a guard's flags drive); () = none.
        guard_dir: a folder with a saved guard (:func:`msta.policies.guard_file.load_guard`) whose
            files are copied into ``output_dir`` and named in the spec.
        robot: the robot the export is for (its name and action convention go into the
            spec; None: :func:`spec_robot` of the student's robots).

    Raises:
        ExportParityError: an exported file's actions differ by more than ``tolerance``
            (the files and the spec, with ``"parity_ok": false``, are still written).
    """
    bad = [f for f in formats if f not in FORMATS]
    if bad or not formats:
        raise ValueError(f"formats must be some of {FORMATS}, got {list(formats)}")
    robot = robot or spec_robot(policy.config.robots)
    policy = policy.cpu().float().eval()
    names = resolve_sensors(policy, sensors)
    T = int(history or (MINIMIZED_HISTORY if sensors == "minimized" else policy.config.history))
    if T < 1:
        raise ValueError(f"history must be >= 1, got {T}")
    out = Path(output_dir)
    out.mkdir(parents=True, exist_ok=True)
    module = DeployedStudent(policy, names, absent)  # ValueError: absent not exported
    windows = dict(windows or {"random": random_windows(policy, names, T, 64)})
    first = next(iter(windows.values()))
    # one removed channel per absent input: the traced graph keeps the removal path
    example = tuple(torch.from_numpy(first[n][:1]) for n in names) + tuple(
        torch.from_numpy(m) for m in trace_masks(module.absent).values())
    runners = _write_formats(module, example, formats, out)
    parity = _parity(module, windows, runners)
    worst = max((p["max_abs_diff"] for p in parity), default=0.0)
    spec = _spec(policy, robot, names, T, formats, parity, worst, tolerance, source)
    spec |= removal_spec(module.absent, guard_dir, out)
    return _write_spec(spec, out)


def _write_spec(spec: dict[str, Any], out: Path) -> dict[str, Any]:
    """Write ``out``/spec.json; then raise ExportParityError when the parity check failed."""
    (out / SPEC_NAME).write_text(json.dumps(spec, indent=1) + "\n")
    worst, tolerance = spec["parity_max_abs_diff"], spec["parity_tolerance"]
    if not worst <= tolerance:
        raise ExportParityError(f"exported actions differ from the eager model's by {worst:.3g} "
                                f"> tolerance {tolerance:g} (per file and window set: "
                                f"{out / SPEC_NAME})")
    return spec


def _write_formats(module: DeployedStudent, example: tuple[torch.Tensor, ...],
                   formats: Sequence[str], out: Path) -> dict[str, Any]:
    """Trace ``module`` on ``example`` into each of ``formats`` under ``out``; returns a
    runner of each written file (inputs in ``module.input_names`` order -> (n, A)) for the
    parity check."""
    names = module.input_names
    runners = {}
    with warnings.catch_warnings(), torch.no_grad():
        # TracerWarnings name the eager path's Python checks, which the graph leaves out
        warnings.simplefilter("ignore")
        if "torchscript" in formats:
            torch.jit.save(torch.jit.trace(module, example, check_trace=False),
                           str(out / TORCHSCRIPT_NAME))
            runners["torchscript"] = _torchscript_runner(out / TORCHSCRIPT_NAME)
        if "onnx" in formats:
            axes = {n: {0: "batch"} for n in names} | {"action": {0: "batch"}}
            torch.onnx.export(module, example, str(out / ONNX_NAME), dynamo=False,
                              input_names=list(names), output_names=["action"],
                              dynamic_axes=axes, opset_version=ONNX_OPSET)
            runners["onnx"] = _onnx_runner(out / ONNX_NAME)
    return runners


def _torchscript_runner(path: Path):
    loaded = torch.jit.load(str(path))

    def run(inputs: Sequence[np.ndarray]) -> np.ndarray:
        with torch.no_grad():
            return loaded(*(torch.from_numpy(x) for x in inputs)).numpy()
    return run


def _onnx_runner(path: Path):
    import onnxruntime as ort  # lazy: onnxruntime loads only where an ONNX graph runs

    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    names = [i.name for i in session.get_inputs()]

    def run(inputs: Sequence[np.ndarray]) -> np.ndarray:
        return session.run(["action"], dict(zip(names, inputs, strict=True)))[0]
    return run


def _parity(module: DeployedStudent, windows: Mapping[str, Mapping[str, np.ndarray]],
            runners: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Max |exported - eager| per (file, window set), batched and at batch 1 (first 8); with
    absent inputs, under random removal masks (:func:`absent_masks`)."""
    rows = []
    for k, (set_name, w) in enumerate(windows.items()):
        inputs = [np.ascontiguousarray(w[n], dtype=np.float32) for n in module.sensors]
        n = len(inputs[0])
        inputs += list(absent_masks(module.absent, n, seed=k).values())
        with torch.no_grad():
            ref = module(*(torch.from_numpy(x) for x in inputs)).numpy()  # (n, A)
        for fmt, run in runners.items():
            diff = float(np.abs(run(inputs) - ref).max())
            for i in range(min(8, len(ref))):  # batch 1, as on the robot
                diff = max(diff, float(np.abs(run([x[i:i + 1] for x in inputs]) - ref[i]).max()))
            rows.append({"format": fmt, "windows": set_name, "count": int(len(ref)),
                         "max_abs_diff": diff} | ({"absent": "random"} if module.absent else {}))
    return rows


def _spec(policy: StudentPolicy, robot: RobotDescription, names: Sequence[str], T: int,
          formats: Sequence[str], parity: list[dict[str, Any]], worst: float, tolerance: float,
          source: Mapping[str, Any] | None) -> dict[str, Any]:
    stats = policy.processor.stats
    inputs = []
    for name in names:
        s = registry.get(name)
        inputs.append({"name": name, "shape": ["batch", T, s.dim], "dtype": "float32",
                       "channels": list(s.names), "description": s.description,
                       "binary": s.binary, "column": s.column,
                       "stats": None if s.binary else stats[s.column]})
    files = {"torchscript": TORCHSCRIPT_NAME, "onnx": ONNX_NAME}
    return {
        "format": FORMAT,
        "policy_type": policy.config.type,
        "robot": robot.name,
        "files": {f: files[f] for f in formats},
        "inputs": inputs,
        "history": T,
        "window": "oldest step first; before T readings exist, repeat the first reading",
        "output": {"name": "action", "shape": ["batch", policy.config.action_dim],
                   "dtype": "float32"},
        "action_convention": {
            "joint_target": "default_pose + action_scale * clip(action, -clip_actions, "
                            "clip_actions)",
            "default_pose": [float(v) for v in robot.default_pose],
            "joint_names": list(robot.joints),
            "action_scale": robot.action_scale, "clip_actions": robot.clip_actions,
            "kp": robot.kp, "kd": robot.kd, "control_dt_s": robot.control_dt,
            "last_action": "feed this step's action back as next step's last_action input",
        },
        "statistics_note": "normalization is inside the graph; stats are listed for reference",
        "parity": parity,
        "parity_max_abs_diff": worst,
        "parity_tolerance": tolerance,
        "parity_ok": bool(worst <= tolerance),
        "torch": torch.__version__,
        "source": dict(source or {}),
    }

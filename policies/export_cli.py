"""``msta-export``'s command line (:class:`ExportConfig`, :func:`main`) and its run: a trained
student -> TorchScript + ONNX + spec.json, parity-checked (the graphs and the check:
:mod:`msta.policies.export`, imported once the command line is parsed)."""

from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from msta.data.cli import parse_config
from msta.data.layout import lerobot_home
from msta.data.torchcodec_warning import shorten_torchcodec_warning
from msta.policies.export_files import (
    DEFAULT_TOLERANCE,
    SPEC_NAME,
    ExportParityError,
)
from msta.policies.export_removal import (
    absent_inputs,
)
from msta.policies.input_spec import MINIMIZED_HISTORY
from msta.policies.registry import get_policy_class
from msta.policies.resolve import resolve_pretrained


@dataclass
class ExportConfig:
    """msta-export: a trained student -> TorchScript + ONNX + spec.json, parity-checked.

    Args:
        policy: checkpoint directory (config.json, model.safetensors, processor.json) or a
            hub repo id ``user/name`` (with --revision).
        revision: hub revision (tag, branch, commit) for a repo id.
        output_dir: where student.pt, student.onnx and spec.json go.
        sensors: ``all`` (every input of the checkpoint), ``minimized`` (command, joint_pos,
            gravity, last_action at T = 7, the paper's deployment observation) or a comma
            list of sensor names.
        history: window length T (0: the checkpoint's training T; 7 with ``minimized``).
        formats: comma list of ``torchscript`` and ``onnx``.
        dataset: dataset root whose recorded windows the parity check uses (empty: the
            dataset named in the checkpoint's train_config.json when it exists here).
        parity_windows: recorded windows checked (evenly spaced over the dataset).
        random_windows: random windows checked (drawn around the statistics).
        tolerance: largest allowed |exported - eager| action difference (fp32: 1e-5).
        seed: seed of the random windows.
        absent_inputs: sensors that get an ``absent_<sensor>`` removal input: ``auto`` (the
            guarded sensors when the checkpoint has a guard, which is copied along; none
            otherwise), ``none``, or a comma list of exported sensors.
        robot: the robot the export is for, whose numbers (joint names, default pose,
            action scale, gains, control period) and name spec.json holds: a shipped robot's
            name or a spec file's path, one the checkpoint was trained on (its config's
            ``robots``); empty: the checkpoint's one robot (a robot that is not shipped is
            given by its spec file; several: pick one).
    """

    policy: str = ""
    revision: str | None = None
    output_dir: str = "outputs/export"
    sensors: str = "all"
    history: int = 0
    formats: str = "torchscript,onnx"
    dataset: str = ""
    parity_windows: int = 256
    random_windows: int = 64
    tolerance: float = DEFAULT_TOLERANCE
    seed: int = 0
    absent_inputs: str = "auto"
    robot: str = ""

    def __post_init__(self) -> None:
        if not self.policy:
            raise ValueError("--policy is required (a checkpoint directory or a hub repo id)")
        if self.history < 0 or self.parity_windows < 0 or self.random_windows < 0:
            raise ValueError("history, parity_windows and random_windows must be >= 0")
        if not (self.tolerance > 0 and math.isfinite(self.tolerance)):
            raise ValueError(f"tolerance must be > 0, got {self.tolerance}")


def training_dataset(checkpoint: Path) -> str | None:
    """The dataset root named by the train_config.json next to (or above) a checkpoint."""
    for d in (checkpoint, *list(checkpoint.parents)[:3]):
        f = d / "train_config.json"
        if f.is_file():
            try:
                root = json.loads(f.read_text()).get("dataset")
            except (OSError, ValueError, AttributeError):
                return None
            if isinstance(root, dict):  # lerobot-train's: {"repo_id": ..., "root": ...}
                root = root.get("root") or _lerobot_cache(root.get("repo_id"))
            return root if isinstance(root, str) and root and (
                Path(root) / "meta" / "info.json").is_file() else None
    return None


def _lerobot_cache(repo_id: Any) -> str | None:
    """Where LeRobot keeps ``repo_id`` when no root was given."""
    return str(lerobot_home() / repo_id) if isinstance(repo_id, str) and repo_id else None


def run(cfg: ExportConfig) -> dict[str, Any]:
    """Export ``cfg.policy`` as ``cfg`` says; returns spec.json's content."""
    # lazy: torch after parsing (--help at once)
    from msta.policies.export import (
        export_student,
        random_windows,
        recorded_windows,
        resolve_sensors,
        spec_robot,
    )
    from msta.policies.factory import load_policy  # lazy: torch after parsing (--help at once)

    directory = Path(resolve_pretrained(cfg.policy, cfg.revision, policy_class=get_policy_class))
    policy = load_policy(directory)
    robot = spec_robot(policy.config.robots, cfg.robot)  # before any work: a wrong robot fails
    names = resolve_sensors(policy, cfg.sensors)
    T = cfg.history or (MINIMIZED_HISTORY if cfg.sensors == "minimized" else policy.config.history)
    windows: dict[str, dict[str, np.ndarray]] = {}
    given = Path(cfg.policy)  # a LeRobot checkpoint resolves to a converted copy elsewhere
    dataset = cfg.dataset or training_dataset(directory) or (
        training_dataset(given) if given.is_dir() else None)
    if dataset and cfg.parity_windows:
        windows["recorded"] = recorded_windows(dataset, names, T, cfg.parity_windows)
    else:
        print("msta-export: no dataset found for the parity check (--dataset): random windows "
              "only", file=sys.stderr)
    if cfg.random_windows or not windows:
        windows["random"] = random_windows(policy, names, T, max(cfg.random_windows, 1), cfg.seed)
    formats = [f.strip() for f in cfg.formats.split(",") if f.strip()]
    source = {"checkpoint": str(cfg.policy), "revision": cfg.revision, "dataset": dataset}
    absent, guard_dir = absent_inputs(cfg.absent_inputs, directory, names)
    print(f"msta-export: {policy.config.type} student for robot {robot.name}, {len(names)} "
          f"sensors ({', '.join(names)}), T = {T} -> {cfg.output_dir}"
          + (f"; removal inputs for {', '.join(absent)}" if absent else "")
          + ("; with its guard" if guard_dir else ""))
    try:
        spec = export_student(policy, cfg.output_dir, cfg.sensors, T, formats, windows,
                              cfg.tolerance, source, absent, guard_dir, robot)
    finally:
        _print_parity(Path(cfg.output_dir) / SPEC_NAME)
    return spec


def _print_parity(spec_path: Path) -> None:
    if not spec_path.is_file():
        return
    spec = json.loads(spec_path.read_text())
    for p in spec["parity"]:
        removal = " (random removal masks)" if p.get("absent") else ""
        print(f"  parity {p['format']:<11} on {p['count']:>4} {p['windows']} windows{removal}: "
              f"max |d action| = {p['max_abs_diff']:.2e}")
    verdict = "ok" if spec["parity_ok"] else "FAILED"
    print(f"parity {verdict}: max |d action| {spec['parity_max_abs_diff']:.2e} "
          f"(tolerance {spec['parity_tolerance']:g}); files: "
          f"{', '.join(spec['files'].values())}, {SPEC_NAME}")


def main(argv: list[str] | None = None) -> None:
    """Console entry point (``msta-export``)."""
    shorten_torchcodec_warning()
    cfg = parse_config(ExportConfig, argv, "msta-export")  # bad flags: one line, exit 2
    try:
        run(cfg)
    except (KeyError, ValueError, FileNotFoundError, NotADirectoryError, ExportParityError) as e:
        msg = e.args[0] if isinstance(e, KeyError) and e.args else e
        print(f"msta-export: error: {msg}", file=sys.stderr)
        raise SystemExit(2) from None


if __name__ == "__main__":
    main()

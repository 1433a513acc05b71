"""msta-eval's settings (:class:`EvalConfig`), read by its command line
(:mod:`msta.eval.evaluate`), the evaluation itself (:mod:`msta.eval.evaluation`) and the apps
that evaluate."""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from msta.collect.faults import FaultSpec, split_faults
from msta.collect.ray_pool import RayOptions, check_ray_options
from msta.eval.scenarios import TrialConfig, get_scenario, get_suite, split_csv
from msta.policies.teacher.config import TeacherConfig

if TYPE_CHECKING:
    import torch


@dataclass
class EvalConfig(TrialConfig, RayOptions):
    """``msta-eval``: the paper's experiments on any checkpoints (docs/eval.md)."""

    policies: str = "teacher"
    """comma-separated entries: teacher, teacher:<type>, checkpoint dirs, hub ids
    user/name[@revision]."""
    output_dir: str = "outputs/eval"
    """output directory."""
    scenarios: str = ""
    """comma-separated scenario names; empty = the suite's."""
    matrix: str = ""
    """checkpoint -> train mask ratios for the heatmaps: ``CKPT=a1:a2,...`` (CKPT as
    written in --policies)."""
    faults: str = ""
    """the sensor_faults scenario's faults, comma-separated one-string forms
    ``TYPE:VALUE:TARGET[/rate=R][/onset=A-B]`` (e.g. ``stuck:0:encoder:2,bias:3:ang_vel``);
    empty = the default sweep (docs/faults.md)."""
    windows: str = ""
    """the history scenario's windows T, comma-separated (e.g. ``2,3,4,5,8`` for a student
    trained at T = 4); empty = the suite's (paper: 3,5,7,10,15,20)."""
    teacher: TeacherConfig = field(default_factory=TeacherConfig)
    """the reference teacher (``--teacher.type=gait``)."""
    video: str = ""
    """``POLICY:TERRAIN[:LEVEL]`` renders a short MP4 of that policy (needs EGL)."""
    video_s: float = 4.0
    """video length (s)."""
    progress: bool = True
    """show progress bars."""
    resume: bool = False
    """reuse what an interrupted msta-eval finished in ``output_dir/eval_runs/`` (a file per
    policy x inputs, or per round of its trials; used only when the trials, the reference
    teacher, the checkpoint and its inputs are the same); false clears eval_runs/ first."""
    max_minutes: float = 0.0
    """stop after this many minutes, at the end of the round of trials in progress, and
    exit with status 75; the same command with --resume=true continues. 0 = no limit."""
    device: str = "auto"
    """where the students run: auto (CUDA when available, else CPU), cpu, cuda, cuda:1...
    The simulator and the teachers stay on the CPU. Figures on CUDA are not bit-identical
    to the CPU's (float rounding), so a stored run is reused only on the same device type."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.robot:  # empty: the checkpoints' robot, resolved by evaluate (a copy naming it)
            self.teacher = self.teacher.on_robot(self.robot, "msta-eval")
        suite = get_suite(self.suite)
        self.policy_list = split_csv(self.policies)
        if not self.policy_list:
            raise ValueError("--policies is empty")
        self.scenario_list = split_csv(self.scenarios) or list(suite.scenarios)
        for s in self.scenario_list:
            get_scenario(s)
        self.matrix_map = _parse_matrix(self.matrix, self.policy_list)
        self.fault_list = [str(FaultSpec.parse(f)) for f in split_faults(self.faults)]
        if self.fault_list and "sensor_faults" not in self.scenario_list:
            raise ValueError("--faults needs --scenarios to include sensor_faults")
        self.window_list = _parse_windows(self.windows)
        if self.window_list and "history" not in self.scenario_list:
            raise ValueError("--windows needs --scenarios to include history")
        check_ray_options(self.workers, self.ray_address)
        if self.workers and self.device not in ("auto", "cpu"):
            raise ValueError(f"--workers runs the students on the workers' CPUs; "
                             f"--device={self.device} needs --workers=0")

    @functools.cached_property
    def torch_device(self) -> torch.device:
        """Where the students run, resolved once: a bad or unavailable ``device`` is a
        one-line ValueError (:func:`msta.policies.factory.select_device`), raised when a run
        starts rather than when the config is built, so ``--help`` needs no torch."""
        from msta.policies.factory import select_device  # lazy: torch when a run starts

        return select_device("cpu" if self.workers else self.device)

    def resolved(self) -> dict[str, Any]:
        """The effective configuration as stored in metrics.json (``out`` left out)."""
        d = super().resolved()
        for k in ("workers", "ray_address"):  # where the trials ran changes no figure
            d.pop(k)
        d.update(device=self.torch_device.type,  # what ran, not "auto"
                 scenarios=self.scenario_list, policies=self.policy_list,
                 matrix={k: list(v) for k, v in self.matrix_map.items()})
        if self.fault_list:  # only when set: other metrics.json files stay as they were
            d["faults"] = self.fault_list
        else:
            d.pop("faults")
        if self.window_list:  # likewise
            d["windows"] = list(self.window_list)
        else:
            d.pop("windows")
        return d


def _parse_windows(text: str) -> tuple[int, ...]:
    """``--windows`` as sorted, distinct window lengths (each a whole number >= 1)."""
    out = set()
    for item in split_csv(text):
        if not item.isdigit() or int(item) < 1:
            raise ValueError(f"--windows: {item!r} is not a window length (a whole number >= 1)")
        out.add(int(item))
    return tuple(sorted(out))


def _parse_matrix(text: str, policies: list[str]) -> dict[str, tuple[float, float]]:
    out = {}
    for item in split_csv(text):
        key, sep, ratios = item.rpartition("=")
        parts = ratios.split(":")
        try:
            a1, a2 = (float(p) for p in parts)
        except ValueError:
            raise ValueError(f"--matrix entry {item!r} must look like CKPT=0.75:0.5") from None
        if not sep or key not in policies:
            raise ValueError(f"--matrix entry {item!r}: {key!r} is not one of --policies "
                             f"{policies}")
        out[key] = (a1, a2)
    return out

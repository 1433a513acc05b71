"""Run an exported student with onnxruntime and numpy only (no torch): the reference
robot-side loop for files written by ``msta-export`` (:mod:`msta.policies.export`).

    student = OnnxStudent("outputs/export")           # reads spec.json + student.onnx
    student.reset()                                   # at every episode start
    action = student.step({"joint_pos": q, "gravity": g, "command": cmd, ...})  # (12,)

:meth:`OnnxStudent.step` keeps the T-step window of every input sensor (the first reading of
an episode fills the whole window, as the dataset reader pads), checks each reading's shape
and finiteness, and, when ``last_action`` is an input the caller does not pass, feeds back
the action it returned on the previous step (zeros after a reset, as the simulator starts).
Joint targets are ``default_pose + action_scale * action`` (spec.json ``action_convention``).

An export with a guard (spec.json ``guard``) also runs it, numpy only
(:class:`msta.policies.guard.SensorGuard`): every step the guard reads the newest readings of all
its sensors (``guard.reads``: pass them all, even those the student does not read), and its
latched flags of the sensors with an ``absent_<sensor>`` input remove those channels from
the student's window (:attr:`OnnxStudent.flags` holds them; :meth:`reset` clears them),
except a gravity vector flagged alone, which a repairing guard replaces by its estimate
carried forward by the gyro (:meth:`msta.policies.guard.SensorGuard.repair`).

This module must not import torch: ``tests/policies/test_export.py`` runs it in a fresh
interpreter and checks ``sys.modules``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from msta.data.sensors import get
from msta.policies.guard import INPUT_SENSORS
from msta.policies.guard_file import load_guard

FORMAT = "msta-export/1"


class OnnxStudent:
    """An exported student on onnxruntime's CPU provider.

    Args:
        export_dir: the ``msta-export`` output directory (spec.json, student.onnx).
        num_threads: onnxruntime intra-op threads (1: one core, as the latency benchmark).
    """

    def __init__(self, export_dir: str | Path, num_threads: int = 1) -> None:
        import onnxruntime as ort  # lazy: onnxruntime loads only where an ONNX graph runs

        d = Path(export_dir)
        spec_path = d / "spec.json"
        if not spec_path.is_file():
            raise FileNotFoundError(f"{d}: no spec.json (write one with msta-export)")
        self.spec: dict[str, Any] = json.loads(spec_path.read_text())
        if self.spec.get("format") != FORMAT:
            raise ValueError(f"{spec_path}: format {self.spec.get('format')!r} is not {FORMAT!r}")
        if "onnx" not in self.spec["files"]:
            raise ValueError(f"{spec_path}: this export has no ONNX file (--formats)")
        options = ort.SessionOptions()
        options.intra_op_num_threads = int(num_threads)
        options.inter_op_num_threads = 1
        self.session = ort.InferenceSession(str(d / self.spec["files"]["onnx"]), options,
                                            providers=["CPUExecutionProvider"])
        self.history = int(self.spec["history"])
        self.dims = {i["name"]: int(i["shape"][2]) for i in self.spec["inputs"]}
        self.action_dim = int(self.spec["output"]["shape"][1])
        #: sensors whose channels the graph can remove per sample (absent_<sensor> inputs)
        self.absent = {a["sensor"]: a["name"] for a in self.spec.get("absent_inputs", [])}
        self.guard = None
        if "guard" in self.spec:
            self.guard = load_guard(d)
        #: the guard's latched flags after the last step, ``{sensor: (dim,) bool}``
        self.flags: dict[str, np.ndarray] = {}
        self._window: dict[str, np.ndarray] | None = None
        self._last_action = np.zeros(self.action_dim, np.float32)

    @property
    def sensors(self) -> list[str]:
        """Input sensor names, in the order the ONNX graph takes them."""
        return list(self.dims)

    def reset(self) -> None:
        """Forget the window (call at every episode start)."""
        self._window = None
        self._last_action = np.zeros(self.action_dim, np.float32)
        self.flags = {}
        if self.guard is not None:
            self.guard.reset()

    def step(self, readings: Mapping[str, Any],
             absent: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
        """One control step: the newest reading of every input sensor (and, with a guard,
        of every sensor it reads) -> the action (12,).

        Args:
            readings: sensor name -> (dim,) reading; ``last_action`` may be omitted (the
                previous returned action is used).
            absent: sensor -> (dim,) bool, channels to remove now (added to the guard's
                flags); only sensors with an ``absent_<sensor>`` input.
        """
        needed = dict(self.dims)
        if self.guard is not None:
            needed |= {s: get(s).dim for s in INPUT_SENSORS if s not in needed}
        current = {name: self._reading(readings, name, dim) for name, dim in needed.items()}
        removed = {s: np.zeros(self.dims[s], bool) for s in self.absent}
        if self.guard is not None:
            step = {s: current[s][None] for s in INPUT_SENSORS}
            flags = self.guard.update(step)
            self.flags = {s: f[0] for s, f in flags.items()}
            if self.guard.repairs:  # a flagged gravity vector replaced, not removed
                fixed, flags = self.guard.repair(step)
                current["gravity"] = np.asarray(fixed["gravity"][0], np.float32)
            removed |= {s: f[0] | removed[s] for s, f in flags.items() if s in removed}
        for s, m in (absent or {}).items():
            if s not in removed:
                raise KeyError(f"{s!r} has no removal input; these do: {list(self.absent)}")
            removed[s] = removed[s] | np.asarray(m, bool).reshape(-1)
        current = {n: current[n] for n in self.dims}
        if self._window is None:  # episode start: the first reading fills the window
            self._window = {n: np.repeat(v[None], self.history, 0) for n, v in current.items()}
        else:
            for name, value in current.items():
                w = self._window[name]  # (T, dim), oldest first
                w[:-1] = w[1:]
                w[-1] = value
        action = self({n: w[None] for n, w in self._window.items()},
                      {s: m[None] for s, m in removed.items()})[0]
        self._last_action = action.copy()
        return action

    def _reading(self, readings: Mapping[str, Any], name: str, dim: int) -> np.ndarray:
        """One sensor's checked (dim,) float32 reading (``last_action`` fed back if absent)."""
        if name not in readings and name == "last_action":
            value = self._last_action
        elif name not in readings:
            raise KeyError(f"missing reading {name!r}; this student reads {self.sensors}"
                           + (" and its guard every physical sensor and the command"
                              if self.guard is not None else ""))
        else:
            value = np.asarray(readings[name], dtype=np.float32).reshape(-1)
        if value.shape != (dim,):
            raise ValueError(f"reading {name!r} has shape {value.shape}, expected ({dim},)")
        if not np.isfinite(value).all():
            raise ValueError(f"reading {name!r} has a non-finite value: {value}")
        return value

    def __call__(self, windows: Mapping[str, np.ndarray],
                 absent: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
        """Batched windows ``{sensor: (B, T, dim)}`` -> actions (B, 12); ``absent``
        ``{sensor: (B, dim) bool}`` for the sensors with a removal input (missing: none)."""
        feed = {n: np.ascontiguousarray(windows[n], dtype=np.float32) for n in self.dims}
        B = len(next(iter(feed.values())))
        for s, name in self.absent.items():
            m = absent.get(s) if absent is not None else None
            feed[name] = (np.zeros((B, self.dims[s]), bool) if m is None
                          else np.ascontiguousarray(m, dtype=bool))
        return self.session.run(["action"], feed)[0]

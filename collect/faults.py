"""Sensor faults: what a lying sensor does to the student's observation (docs/faults.md).

A :class:`FaultSpec` names one fault: its type, severity, target channels, onset window and
(spikes, dropout) rate. A :class:`FaultInjector` applies it to a batch of observations, one
control step per :meth:`~FaultInjector.apply`, each environment with its own onset (drawn
uniformly in ``onset_s`` at every :meth:`~FaultInjector.reset`, from a seeded generator). A
:class:`FaultyActor` puts an injector between the simulator and a student actor, so faults
reach the student's observation only: the simulator's state, the teacher's inputs and the
recorded privileged signals never see them. It optionally removes channels from the
student's input: the *oracle* removes exactly the fault's channels where it is active; a
*guard* (``msta.policies.guard``) removes what it flags (a gravity vector flagged alone it
repairs: ``SensorGuard.repair``).

Fault models, from the onset step on (``x`` the true reading, ``std`` the channel's std in
the student's normalization statistics, ``k`` the severity, ``t`` the seconds since onset):

========  ================================================================================
stuck     the reading at the onset step, held
bias      ``x + k std``
drift     ``x + k std t`` (``t = 0`` at the onset step)
noise     ``x + k std z``, ``z ~ N(0, 1)`` per channel and step
spikes    ``x ± k std`` (random sign) on a fraction ``rate`` of steps, per channel
dropout   on a fraction ``rate`` of steps (per environment and step, all target channels
          at once) the reading is missing: the last delivered reading is held
scale     ``k x``
========  ================================================================================

Binary sensors (foot_contact, 0/1) take stuck, dropout and spikes (a spike flips the
reading: ``1 - x``); bias, drift, noise and scale are refused (they have no meaning on a
0/1 flag and the student thresholds it at 0.5).

One-string form (the command line's ``--faults``): ``TYPE:VALUE:TARGET[/rate=R][/onset=A-B]``
with VALUE the severity (any number for stuck; the rate for dropout), TARGET ``SENSOR``
(every channel), ``SENSOR:i`` or ``SENSOR:i,j`` (channels), or ``encoder:j[,k]`` (joint
j's q and q-dot), e.g. ``stuck:0:encoder:2``, ``bias:3:joint_pos:5``,
``spikes:5:gravity/rate=0.05``, ``dropout:0.2:foot_contact``, ``drift:0.5:joint_pos:2/onset=0.5-1``.

numpy only (the guard and the robot loop import nothing heavier).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from msta.data.sensors import JOINT_ENCODER_SENSORS, PHYSICAL_SENSORS, get
from msta.data.stats import MIN_STD

FAULT_TYPES: tuple[str, ...] = ("stuck", "bias", "drift", "noise", "spikes", "dropout", "scale")
#: The target that names one joint encoder: its q (joint_pos) and q-dot (joint_vel).
ENCODER = "encoder"
#: The fault types a binary sensor (0/1) can take.
BINARY_FAULTS: tuple[str, ...] = ("stuck", "spikes", "dropout")
#: The fault types whose size is a multiple of the channel's std.
STD_FAULTS: tuple[str, ...] = ("bias", "drift", "noise", "spikes")
#: The latest onset (s): an hour, beyond any episode (later ones overflowed the step count).
MAX_ONSET_S = 3600.0
#: The largest severity (std multiples, either sign).
MAX_SEVERITY = 1000.0
_FORM = "TYPE:VALUE:TARGET[/rate=R][/onset=A-B], e.g. bias:3:encoder:2"


def _channels(target: str) -> dict[str, tuple[int, ...]]:
    """``target`` -> {sensor: channel indices}; ValueError (one line) when malformed."""
    name, sep, rest = target.partition(":")
    sensors = JOINT_ENCODER_SENSORS if name == ENCODER else (name,)
    if name != ENCODER and name not in PHYSICAL_SENSORS:
        raise ValueError(f"fault target {target!r}: {name!r} is not a physical sensor "
                         f"({', '.join(PHYSICAL_SENSORS)}) or {ENCODER!r}")
    if name == ENCODER and not rest:
        raise ValueError(f"fault target {target!r}: name the joint, e.g. {ENCODER}:2")
    dim = get(sensors[0]).dim
    if not sep:
        return {s: tuple(range(dim)) for s in sensors}
    try:
        idx = tuple(int(p) for p in rest.split(","))
    except ValueError:
        raise ValueError(f"fault target {target!r}: channels must be integers like "
                         f"{name}:3 or {name}:3,7") from None
    if len(set(idx)) != len(idx) or min(idx) < 0 or max(idx) >= dim:
        raise ValueError(f"fault target {target!r}: channels must be distinct indices in "
                         f"[0, {dim})")
    return {s: tuple(sorted(idx)) for s in sensors}


@dataclass(frozen=True)
class FaultSpec:
    """One sensor fault.

    Args:
        type: one of :data:`FAULT_TYPES`.
        severity: std multiples (bias, noise, spikes), std per second (drift), a factor
            (scale: reading * severity); unused by stuck and dropout.
        target: ``"joint_pos:3"``, ``"joint_pos:3,7"``, ``"ang_vel"`` or ``"encoder:3"``.
        onset_s: the onset is drawn uniformly in this window (s after the episode start).
        rate: fraction of steps hit (spikes: per channel; dropout: per environment).
    """

    type: str
    severity: float
    target: str
    onset_s: tuple[float, float] = (1.0, 3.0)
    rate: float = 0.1

    def __post_init__(self) -> None:
        object.__setattr__(self, "onset_s", tuple(float(v) for v in self.onset_s))
        object.__setattr__(self, "severity", float(self.severity))
        object.__setattr__(self, "rate", float(self.rate))
        if self.type not in FAULT_TYPES:
            raise ValueError(f"unknown fault type {self.type!r}; known: {', '.join(FAULT_TYPES)}")
        chans = _channels(self.target)
        if not abs(self.severity) <= MAX_SEVERITY:  # NaN fails too
            raise ValueError(f"fault {self}: severity must be a finite number in "
                             f"[-{MAX_SEVERITY:g}, {MAX_SEVERITY:g}] (std multiples)")
        if self.type in ("noise", "spikes") and self.severity < 0:
            raise ValueError(f"fault {self}: {self.type} severity must be >= 0 (std multiples)")
        if not 0.0 <= self.rate <= 1.0:
            raise ValueError(f"fault {self}: rate must be in [0, 1], got {self.rate:g}")
        lo, hi = (self.onset_s + (math.nan, math.nan))[:2]
        if len(self.onset_s) != 2 or not 0.0 <= lo <= hi <= MAX_ONSET_S:
            raise ValueError(f"fault {self}: onset_s must be (low, high) with 0 <= low <= high "
                             f"<= {MAX_ONSET_S:g} s")
        binary = [s for s in chans if get(s).binary]
        if binary and self.type not in BINARY_FAULTS:
            raise ValueError(f"fault {self}: {binary[0]} is binary (0/1); it takes "
                             f"{', '.join(BINARY_FAULTS)}")

    @property
    def channels(self) -> dict[str, np.ndarray]:
        """{sensor: channel indices} the fault touches (full-channel, registry order)."""
        return {s: np.asarray(i, dtype=np.int64) for s, i in _channels(self.target).items()}

    @classmethod
    def parse(cls, text: str) -> FaultSpec:
        """The one-string form (module docstring); ValueError with one line when bad."""
        head, *opts = str(text).strip().split("/")
        m = re.fullmatch(r"([a-z_]+):([^:]+):(.+)", head)
        if m is None:
            raise ValueError(f"fault {text!r} must look like {_FORM}")
        kind, value, target = m.groups()
        try:
            number = float(value)
        except ValueError:
            raise ValueError(f"fault {text!r}: {value!r} is not a number ({_FORM})") from None
        kw: dict[str, Any] = {"rate": number} if kind == "dropout" else {}
        for opt in opts:
            key, sep, val = opt.partition("=")
            try:
                if key == "rate" and sep and kind != "dropout":
                    kw["rate"] = float(val)
                elif key == "onset" and sep:
                    lo, _, hi = val.partition("-")
                    kw["onset_s"] = (float(lo), float(hi or lo))
                else:
                    raise ValueError
            except ValueError:
                raise ValueError(f"fault {text!r}: option {opt!r} must be rate=R (spikes) or "
                                 f"onset=A-B ({_FORM})") from None
        return cls(kind, 0.0 if kind == "dropout" else number, target, **kw)

    def __str__(self) -> str:
        value = self.rate if self.type == "dropout" else self.severity
        text = f"{self.type}:{value:g}:{self.target}"
        if self.type == "spikes" and self.rate != 0.1:
            text += f"/rate={self.rate:g}"
        if self.onset_s != (1.0, 3.0):
            text += f"/onset={self.onset_s[0]:g}-{self.onset_s[1]:g}"
        return text

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready (metrics.json), with the one-string form."""
        return {"spec": str(self), "type": self.type, "severity": self.severity,
                "target": self.target, "onset_s": list(self.onset_s), "rate": self.rate}


def split_faults(text: str) -> list[str]:
    """A comma-separated list of one-string faults, where a target's own channel list
    (``joint_pos:3,7``) stays with its fault: an item that is only an integer joins the
    previous one."""
    out: list[str] = []
    for part in (p.strip() for p in str(text).split(",")):
        if part and part.isdigit() and out:
            out[-1] += f",{part}"
        elif part:
            out.append(part)
    return out


def std_from_stats(stats: Mapping[str, Mapping[str, Any]], sensors: Sequence[str]
                   ) -> dict[str, np.ndarray]:
    """{sensor: (dim,) std} from a student processor's statistics (``policy.processor.
    stats``, keyed by dataset column), the std it z-scores with (1 below
    :data:`msta.data.stats.MIN_STD`, as ``msta.policies.processor.effective_std``); binary
    sensors and sensors without statistics are left out."""
    out = {}
    for s in sensors:
        spec = get(s)
        if not spec.binary and spec.column in stats:
            std = np.asarray(stats[spec.column]["std"], dtype=np.float64).reshape(-1)
            out[s] = np.where(std < MIN_STD, 1.0, std)
    return out


class FaultInjector:
    """Applies one :class:`FaultSpec` to a batch of observations, step by step.

    Args:
        spec: the fault.
        num_envs: environments in the batch.
        std: {sensor: (dim,) std} (:func:`std_from_stats`); needed for the target sensors
            of bias, drift, noise and spikes on continuous sensors.
        dt: control step (s).
        seed: seeds the onsets (one generator) and the per-step draws (another), so the
            onsets do not depend on how many steps ran.
    """

    def __init__(self, spec: FaultSpec, num_envs: int, std: Mapping[str, np.ndarray] | None = None,
                 dt: float = 0.02, seed: int | Sequence[int] = 0) -> None:
        self.spec, self.num_envs, self.dt = spec, int(num_envs), float(dt)
        self.channels = spec.channels
        self.binary = {s: get(s).binary for s in self.channels}
        self._size: dict[str, np.ndarray] = {}
        for s, idx in self.channels.items():
            if spec.type in STD_FAULTS and not self.binary[s]:
                if std is None or s not in std:
                    raise KeyError(f"fault {spec}: no std for sensor {s!r} (the student's "
                                   "statistics)")
                self._size[s] = spec.severity * np.asarray(std[s], dtype=np.float64)[idx]
        onset_seq, step_seq = np.random.SeedSequence(seed).spawn(2)
        self._onset_rng = np.random.default_rng(onset_seq)
        self._rng = np.random.default_rng(step_seq)
        n = self.num_envs
        self.t = np.zeros(n, dtype=np.int64)  # steps since reset (the next apply's step)
        self.onset = np.zeros(n, dtype=np.int64)
        self.active = np.zeros(n, dtype=bool)
        self._held = {s: np.zeros((n, len(i))) for s, i in self.channels.items()}
        self.reset(np.arange(n))

    def reset(self, ids: np.ndarray) -> None:
        """Environments ``ids`` start new episodes: fault off, a new onset step each."""
        ids = np.asarray(ids, dtype=np.int64)
        lo, hi = self.spec.onset_s
        self.onset[ids] = np.round(self._onset_rng.uniform(lo, hi, len(ids)) / self.dt)
        self.t[ids] = 0
        self.active[ids] = False

    def apply(self, obs: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """This step's observation with the fault applied (a new dict; the target sensors'
        arrays copied, the others shared); advances one step."""
        active = self.t >= self.onset
        out = dict(obs)
        draws = self._draw()
        for s, idx in self.channels.items():
            x = np.array(obs[s], copy=True)
            true = x[:, idx].astype(np.float64)
            faulty = self._faulty(s, true, active, draws)
            x[:, idx] = np.where(active[:, None], faulty, true)
            out[s] = x
        self.active = active
        self.t += 1
        return out

    def _draw(self) -> dict[str, Any]:
        """This step's random numbers, drawn for every environment whether active or not."""
        n, kind, rng = self.num_envs, self.spec.type, self._rng
        if kind == "noise":
            return {s: rng.standard_normal((n, len(i))) for s, i in self.channels.items()}
        if kind == "spikes":
            return {s: (rng.random((n, len(i))) < self.spec.rate,
                        np.where(rng.random((n, len(i))) < 0.5, -1.0, 1.0))
                    for s, i in self.channels.items()}
        if kind == "dropout":
            return {"drop": rng.random(n) < self.spec.rate}
        return {}

    def _faulty(self, s: str, x: np.ndarray, active: np.ndarray, draws: dict) -> np.ndarray:
        """The fault's reading of sensor ``s`` (``x``: (N, c) true values) for every env."""
        kind, k = self.spec.type, self.spec.severity
        if kind == "stuck":
            first = active & (self.t == self.onset)
            self._held[s][first] = x[first]
            return self._held[s]
        if kind == "dropout":
            # the first step of an episode always delivers (nothing delivered yet to hold)
            drop = (draws["drop"] & active & (self.t > 0))[:, None]
            self._held[s] = np.where(drop, self._held[s], x)
            return self._held[s]
        if kind == "scale":
            return k * x
        if kind == "spikes":
            hit, sign = draws[s]
            return np.where(hit, 1.0 - x if self.binary[s] else x + sign * self._size[s], x)
        if kind == "bias":
            return x + self._size[s]
        if kind == "drift":
            since = (self.t - self.onset) * self.dt
            return x + self._size[s] * since[:, None]
        return x + self._size[s] * draws[s]  # noise

    def absent(self) -> dict[str, np.ndarray]:
        """{sensor: (N, dim) bool}: the fault's channels on the environments where it was
        active at the last :meth:`apply` (the oracle's removal)."""
        out = {}
        for s, idx in self.channels.items():
            mask = np.zeros((self.num_envs, get(s).dim), dtype=bool)
            mask[np.ix_(self.active, idx)] = True
            out[s] = mask
        return out


class FaultyActor:
    """A student actor whose observations pass through a :class:`FaultInjector`.

    Each step: inject; then remove channels (``oracle``: the injector's :meth:`absent`;
    ``guard``: what ``guard.update(faulty_obs)`` flags, less what ``guard.repair`` replaces
    where the guard repairs; neither: nothing); then ``actor.act(faulty_obs, absent=...)``
    (``absent`` passed only when a channel is removed).

    It records, per environment of the current episodes, the step of the first removal of a
    fault channel at or after onset (``detected``, -1 before; the oracle's is the onset),
    and the removed channel-steps that are not the active fault's (``false_alarms``) out
    of ``channel_steps`` removable ones (:meth:`detections`).

    Args:
        actor: a student actor (``msta.policies.actor.StudentActor``) or anything with
            ``act(obs[, absent=])`` / ``reset(ids)``.
        injector: the fault.
        guard: a detector with ``reset(ids)`` / ``update(obs) -> {sensor: (N, dim) bool}``.
        oracle: remove exactly the fault's active channels (the upper bound).
        record: keep every step's removal (``self.removed``, a list of dicts) for tests.
    """

    def __init__(self, actor: Any, injector: FaultInjector, guard: Any = None,
                 oracle: bool = False, record: bool = False) -> None:
        if oracle and guard is not None:
            raise ValueError("FaultyActor: the oracle and a guard exclude each other")
        self.actor, self.injector, self.guard, self.oracle = actor, injector, guard, oracle
        self.num_envs = injector.num_envs
        self.removed: list[dict[str, np.ndarray]] | None = [] if record else None
        n = self.num_envs
        self.detected = np.full(n, -1, dtype=np.int64)
        self.false_alarms = np.zeros(n, dtype=np.int64)
        self.channel_steps = np.zeros(n, dtype=np.int64)
        self.false_by_step: list[np.ndarray] = []  # (N,) false removals of every step

    def reset(self, ids: np.ndarray) -> None:
        """Environments ``ids`` start new episodes (injector, guard, actor, records)."""
        self.injector.reset(ids)
        if self.guard is not None:
            self.guard.reset(ids)
        self.actor.reset(ids)
        self.detected[ids] = -1
        self.false_alarms[ids] = 0
        self.channel_steps[ids] = 0
        if len(ids) == self.num_envs:
            self.false_by_step = []

    def act(self, obs: Mapping[str, np.ndarray]) -> np.ndarray:
        """(N, 12) actions of the student on this step's faulty observation."""
        faulty = self.injector.apply(obs)
        absent = None
        if self.oracle:
            absent = self.injector.absent()
        elif self.guard is not None:
            absent = self.guard.update(faulty)
        if absent is not None:
            self._score(absent)  # what was flagged: a repaired channel counts as found
        if self.guard is not None and getattr(self.guard, "repairs", False):
            faulty, absent = self.guard.repair(faulty)
        if self.removed is not None:
            self.removed.append({s: m.copy() for s, m in (absent or {}).items()})
        reads = getattr(self.actor, "sensors", None)  # a sensor it does not read: nothing
        if absent is not None and reads is not None:
            absent = {s: m for s, m in absent.items() if s in reads}
        if absent is None or not any(m.any() for m in absent.values()):
            return self.actor.act(faulty)
        return self.actor.act(faulty, absent=absent)

    def _score(self, removed: Mapping[str, np.ndarray]) -> None:
        inj = self.injector
        truth = inj.absent()
        step = inj.t - 1
        hit = np.zeros(self.num_envs, dtype=bool)
        false = np.zeros(self.num_envs, dtype=np.int64)
        for s, m in removed.items():
            m = np.asarray(m, dtype=bool)
            t = truth.get(s, np.zeros_like(m))
            hit |= (m & t).any(axis=1)
            false += (m & ~t).sum(axis=1)
            self.channel_steps += m.shape[1]
        self.false_alarms += false
        self.false_by_step.append(false)
        new = hit & (self.detected < 0)
        self.detected[new] = step[new]

    def detections(self) -> dict[str, np.ndarray]:
        """Per environment: ``onset`` and ``detected`` steps (-1: not detected), the delay
        in steps (``detected - onset``; -1 when not detected), ``false_alarms`` and
        ``channel_steps``; ``false_by_step`` (steps, N): the false removals of every step
        since the last reset of all environments (to count a trial's live steps only)."""
        onset, det = self.injector.onset.copy(), self.detected.copy()
        n = self.num_envs
        return {"onset": onset, "detected": det,
                "delay": np.where(det >= 0, det - onset, -1),
                "false_alarms": self.false_alarms.copy(),
                "channel_steps": self.channel_steps.copy(),
                "false_by_step": (np.stack(self.false_by_step) if self.false_by_step
                                  else np.zeros((0, n), dtype=np.int64))}

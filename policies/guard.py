"""The guard: an online detector that flags faulty sensor channels from the observation
stream alone (docs/faults.md, "The guard"). Numpy only at run time.

Every step it computes a vector of non-negative statistics, each tied to the channels it
accuses; a statistic above its threshold flags those channels, and flags latch until
:meth:`SensorGuard.reset`. The statistics:

* ``z``: each physical channel predicted by ridge regression from every *other* channel
  (its joint encoder's partner excluded) at t, t-1, t-2; the residual's z-score at this
  step (spikes, large jumps), its mean over ``window`` steps (bias, drift, stuck) and its
  mean square (noise).
* ``z2`` (``two_sided``): each physical channel's reading one step back, ``x_{t-1}``,
  predicted from every input at t, t-1, t-2 but itself at t-1 (so its own neighbours on
  both sides); the residual's z-score (a one-step-late spike test) and its mean square
  over ``window`` steps (noise).

With ``explain``, a channel accused only by predictor statistics must still be accused
once the suspects' residuals (channels flagged, or accused by any statistic this step)
are taken out of its prediction: the predictors are linear, so a suspect's residual times
its weight is what it moved the prediction by. A fault then flags its own channels and
not the healthy ones it distorts.
* ``enc``: a joint encoder's own physics, ``q_t - q_{t-1}`` against
  ``dt (qdot_t + qdot_{t-1}) / 2``; now and averaged over ``window`` steps.
* ``repeat``: steps a (non-binary) channel has repeated its last reading exactly.
* ``gnorm``: the gravity vector's distance from unit norm.
* ``imu``: the gyro against the gravity vector's change over ``imu_window`` steps
  (``dg/dt = -w x g`` in the base frame). Without ``imu_attribution`` it accuses the whole
  IMU (ang_vel and gravity). With it, it accuses one half: the half other statistics
  accuse (or have flagged) when only one is; else, ``imu_delay`` steps after it first
  fires, the shape of its residual decides (the window's residual is the sum of one-step
  residuals: a gravity fault enters as a jump, one step carrying at least ``imu_jump`` of
  it; a gyro fault builds up over the steps).
* ``binary``: a contact reading's distance from 0 or 1.
* ``contact`` (``contact_model``): each foot contact's reading one step back against a
  small network's probability of that contact from every other physical and software
  input over the last ``contact_lags`` steps; the reading's surprise ``-log p(reading)``
  averaged over ``window`` steps. It is held at 0 on a robot while any non-contact channel
  is flagged or accused (the network's inputs are then not to be trusted).

With ``repair_gravity``, a gravity vector flagged alone is not removed but replaced by the
last trusted one carried forward by the gyro (:meth:`SensorGuard.repair`,
``policies/guard_imu.py``).

Every statistic is 0 for the first ``warmup`` steps of an episode (a robot dropped at its
spawn point settles first; the calibration sees the same zeros).

Thresholds are the largest value each statistic takes on fault-free calibration episodes
times ``margin`` (``margin2`` for ``z2_sq``, ``contact_margin`` for ``contact``)
(``train/guard_fit.py`` fits and calibrates: ``msta-guard fit``). A joint encoder's q and q-dot
are flagged together.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msta.data import sensors as registry
from msta.data.sensors import PHYSICAL_SENSORS
from msta.policies.guard_imu import ImuRules

FORMAT = 1
#: What the guard reads: the physical sensors, then the software inputs its predictors use.
INPUT_SENSORS: tuple[str, ...] = PHYSICAL_SENSORS + ("command", "last_action")
NJ = registry.NUM_JOINTS
P = registry.total_dim(PHYSICAL_SENSORS)  # 34 physical channels
D = registry.total_dim(INPUT_SENSORS)  # 49 inputs
OFFSET = {s: registry.total_dim(INPUT_SENSORS[:i]) for i, s in enumerate(INPUT_SENSORS)}
#: Config a guard saved before a setting existed gets for it (its behaviour then).
LEGACY_CONFIG = {"two_sided": False, "explain": False, "imu_attribution": False,
                 "contact_model": False, "repair_gravity": False, "warmup": 0}
CONTACTS = np.arange(OFFSET["foot_contact"], OFFSET["foot_contact"] + 4)
#: The contact network's inputs at one step: every input but the contacts.
CONTACT_INPUTS = np.setdiff1d(np.arange(D), CONTACTS)
#: The physical channels but the contacts (the contact network trusts them or not).
NOT_CONTACTS = np.setdiff1d(np.arange(P), CONTACTS)


#: Bounds of the integer settings (steps, lags, units): beyond them the guard's buffers alone
#: would take gigabytes. Float settings are finite and in (0, 1e6].
_INT_RANGES = {"window": (1, 1000), "imu_window": (1, 1000), "min_repeat": (1, 1000),
               "contact_lags": (1, 100), "contact_hidden": (1, 4096), "imu_delay": (0, 1000),
               "warmup": (0, 100_000)}
_FLOAT_MAX = 1e6
#: Arrays that divide: finite and > 0 (a zero scale would switch statistics off).
SCALE_ARRAYS = ("feat_std", "z_std", "enc_std", "z2_std", "contact_std")


@dataclass
class GuardConfig:
    """How the guard decides.

    Args:
        window: steps averaged by the windowed statistics (bias, noise, encoder drift).
        imu_window: steps over which the gyro is checked against the gravity vector.
        ridge: ridge penalty of the per-channel predictors (on standardized features).
        margin: threshold = margin x the largest fault-free value of each statistic.
        min_repeat: a channel repeating its reading exactly for more steps than this (or
            than the calibration data ever showed, whichever is larger) is stuck.
        binary_tolerance: smallest threshold of a contact reading's distance from 0/1.
        two_sided: add the two-sided statistics ``z2`` (spikes and noise one step late).
        margin2: the margin of the two-sided windowed mean square ``z2_sq`` (its fault-free
            tails are longer); every other statistic takes ``margin``.
        explain: a channel accused only by predictor statistics is flagged only if they
            still exceed once the suspect channels' residuals are taken out of its
            prediction (a fault on one channel distorts the others' predictions).
        imu_attribution: the IMU check blames the gyro or the gravity vector, not both
            (see the module's docstring); off, it removes the whole IMU.
        imu_delay: steps after the IMU check first fires before its residual's shape
            decides which half lies (other statistics may decide sooner).
        imu_jump: share of the IMU residual one step must carry for the gravity vector to
            be blamed (fault-free noise aside, a gravity fault puts ~1 in one step, a gyro
            fault ~1 / steps since onset).
        contact_model: add the ``contact`` statistics: each foot contact against a small
            network's prediction from the other inputs (a stuck contact).
        contact_lags: steps of the other inputs the contact network reads (t back to
            t - contact_lags + 1; it judges the reading at t - 1).
        contact_hidden: width of the contact network's two hidden layers.
        contact_epochs: passes over the fitting data when the contact network is fitted.
        contact_margin: the margin of the ``contact`` statistics (the network's held-out
            surprise runs above its fitted one).
        warmup: steps of an episode before the guard judges (its statistics are 0 until
            then, in calibration too): a robot dropped at its spawn point settles first.
        repair_gravity: once the gravity vector alone is flagged, feed the student the
            last trusted one carried forward by the gyro instead of removing it
            (``SensorGuard.repair``; students fall without their gravity vector).
    """

    window: int = 8
    imu_window: int = 10
    ridge: float = 1.0
    margin: float = 1.6
    min_repeat: int = 2
    binary_tolerance: float = 0.01
    two_sided: bool = True
    margin2: float = 2.0
    explain: bool = True
    imu_attribution: bool = True
    imu_delay: int = 2
    imu_jump: float = 0.5
    contact_model: bool = True
    contact_lags: int = 6
    contact_hidden: int = 64
    contact_epochs: float = 10.0
    contact_margin: float = 1.8
    repair_gravity: bool = True
    warmup: int = 50

    def __post_init__(self) -> None:
        for name, (low, high) in _INT_RANGES.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
                raise ValueError(f"guard {name} must be an integer in [{low}, {high}], "
                                 f"got {value!r}")
        for name in ("ridge", "margin", "binary_tolerance", "margin2", "imu_jump",
                     "contact_epochs", "contact_margin"):
            value = getattr(self, name)
            if (isinstance(value, bool) or not isinstance(value, int | float)
                    or not 0 < value <= _FLOAT_MAX):
                raise ValueError(f"guard {name} must be a number in (0, {_FLOAT_MAX:g}], "
                                 f"got {value!r}")


def encoder_partner(c: np.ndarray) -> np.ndarray:
    """Physical channel -> its joint-encoder partner (q <-> q-dot); itself otherwise."""
    return np.where(c < NJ, c + NJ, np.where(c < 2 * NJ, c - NJ, c))


def nonbinary_channels() -> np.ndarray:
    binary = [c for s in PHYSICAL_SENSORS if registry.get(s).binary
              for c in range(OFFSET[s], OFFSET[s] + registry.get(s).dim)]
    return np.array([c for c in range(P) if c not in binary])


def array_shapes(cfg: GuardConfig) -> dict[str, tuple[int, ...]]:
    """The fitted arrays a guard with settings ``cfg`` holds (their names in
    guard.safetensors), and their shapes: the two-sided arrays with ``two_sided``, the
    contact network's (``contact_*``) with ``contact_model``."""
    shapes = {"feat_mean": (3 * D,), "feat_std": (3 * D,), "weight": (3 * D, P), "bias": (P,),
              "z_std": (P,), "enc_std": (NJ,),
              "threshold": (len(statistic_layout(cfg.two_sided, cfg.contact_model)[0]),)}
    if cfg.two_sided:
        shapes |= {"weight2": (3 * D, P), "bias2": (P,), "z2_std": (P,)}
    if cfg.contact_model:
        f, h = cfg.contact_lags * len(CONTACT_INPUTS), cfg.contact_hidden
        shapes |= {"contact_mean": (f,), "contact_std": (f,), "contact_w0": (f, h),
                   "contact_b0": (h,), "contact_w1": (h, h), "contact_b1": (h,),
                   "contact_w2": (h, len(CONTACTS)), "contact_b2": (len(CONTACTS),)}
    return shapes


def statistic_layout(two_sided: bool = False,
                     contact: bool = False) -> tuple[list[str], np.ndarray]:
    """Names of the statistics (one per entry of the vector) and which physical channels
    each one accuses: ``(names, accuse (S, P) bool)``."""
    eye = np.eye(P, dtype=bool)
    enc = eye | eye[encoder_partner(np.arange(P))]  # a channel and its encoder partner
    names, rows = [], []
    for kind in ("z", "z_mean", "z_sq") + (("z2", "z2_sq") if two_sided else ()):
        names += [f"{kind}:{c}" for c in range(P)]
        rows.append(enc)
    for kind in ("enc", "enc_mean"):
        names += [f"{kind}:{j}" for j in range(NJ)]
        rows.append(enc[:NJ])
    nb = nonbinary_channels()
    names += [f"repeat:{c}" for c in nb]
    rows.append(enc[nb])
    imu = np.zeros((2, P), bool)
    imu[0, OFFSET["gravity"]:OFFSET["gravity"] + 3] = True
    imu[1, OFFSET["ang_vel"]:OFFSET["ang_vel"] + 3] = True
    imu[1, OFFSET["gravity"]:OFFSET["gravity"] + 3] = True
    names += ["gnorm", "imu"]
    rows.append(imu)
    names += [f"binary:{c}" for c in CONTACTS]
    rows.append(eye[CONTACTS])
    if contact:
        names += [f"contact:{c}" for c in CONTACTS]
        rows.append(eye[CONTACTS])
    return names, np.concatenate(rows)


class SensorGuard(ImuRules):
    """Online fault detector for ``num_envs`` robots.

    Args:
        cfg: the decision settings.
        stats: the fitted arrays that ``cfg`` asks for (names and shapes in guard.safetensors:
            :func:`array_shapes`):
            feature mean/std (3 D,), ridge weight (3 D, P) and bias (P,), residual std
            ``z_std`` (P,), encoder residual std ``enc_std`` (12,), the contact network and
            one threshold per statistic (S,).
        sensors: the physical sensors whose flags it reports (others are never flagged).
        num_envs: robots stepped together.
        dt: control period (s).
    """

    def __init__(self, cfg: GuardConfig, stats: dict[str, np.ndarray],
                 sensors: tuple[str, ...] = PHYSICAL_SENSORS, num_envs: int = 1,
                 dt: float = 0.02) -> None:
        shapes = array_shapes(cfg)
        missing = [k for k in shapes if k not in stats]
        if missing:
            raise KeyError(f"guard arrays missing: {missing}")
        for k, shape in shapes.items():
            a = np.asarray(stats[k], np.float64)
            if k == "threshold":  # may be +inf (a probe that never fires); a file may not
                ok, want = not np.isnan(a).any() and (a >= 0).all(), "not NaN and >= 0"
            else:
                ok = np.isfinite(a).all() and (k not in SCALE_ARRAYS or (a > 0).all())
                want = "finite and > 0" if k in SCALE_ARRAYS else "finite"
            if not ok or a.shape != shape:
                raise ValueError(f"guard array {k!r} must be {want} with shape {shape}, got "
                                 f"shape {a.shape}")
        bad = [s for s in sensors if s not in PHYSICAL_SENSORS]
        if bad or not sensors:
            raise ValueError(f"guard sensors must be a non-empty subset of {PHYSICAL_SENSORS}, "
                             f"got {list(sensors)}")
        if num_envs < 1 or not 0 < dt <= 1:
            raise ValueError(f"guard needs num_envs >= 1 and 0 < dt <= 1 s, got {num_envs}, {dt}")
        self.cfg, self.sensors, self.num_envs, self.dt = cfg, tuple(sensors), num_envs, dt
        self.stats = {k: np.asarray(stats[k], np.float64) for k in shapes}
        self.names, accuse = statistic_layout(cfg.two_sided, cfg.contact_model)
        keep = np.zeros(P, bool)
        for s in self.sensors:
            keep[OFFSET[s]:OFFSET[s] + registry.get(s).dim] = True
        self.accuse = (accuse & keep).astype(np.float64)  # (S, P)
        self._nb = nonbinary_channels()
        self.flags = np.zeros((num_envs, P), bool)
        self.age = np.zeros(num_envs, np.int64)
        n, k = cfg.window, cfg.imu_window
        self._lag = np.zeros((num_envs, 2, D))  # x_{t-1}, x_{t-2}
        self._zbuf = np.zeros((num_envs, n, P))
        self._z2buf = np.zeros((num_envs, n, P))
        self._rbuf = np.zeros((num_envs, n + 2, P))  # z of the last n + 2 steps
        self._influence = self._influences()
        self._ebuf = np.zeros((num_envs, n, NJ))
        self._cbuf = np.zeros((num_envs, k + 1, 3))  # w x g
        self._gbuf = np.zeros((num_envs, k + 1, 3))
        self._wbuf = np.zeros((num_envs, k + 1, 3))  # the gyro
        self._ghat = np.zeros((num_envs, 3))  # the repaired gravity vector
        self._repairing = np.zeros(num_envs, bool)
        self._rep = np.zeros((num_envs, len(self._nb)))
        self._imu_row = self.names.index("imu")
        self._pending = np.full(num_envs, -1)  # steps since the IMU check fired, undecided
        self._clag = np.zeros((num_envs, cfg.contact_lags, len(CONTACT_INPUTS)))  # newest first
        self._ubuf = np.zeros((num_envs, n, len(CONTACTS)))  # contact surprise
        self._t = 0  # ring position, shared by all envs

    def reset(self, ids: np.ndarray | list[int] | None = None) -> None:
        """New episodes for ``ids`` (None: all): flags cleared, history forgotten."""
        ids = np.arange(self.num_envs) if ids is None else np.asarray(ids, np.int64)
        self.flags[ids] = False
        self.age[ids] = 0
        self._rep[ids] = 0.0
        self._pending[ids] = -1
        self._repairing[ids] = False

    def _concat(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        parts = []
        for s in INPUT_SENSORS:
            if s not in obs:
                raise KeyError(f"the guard reads {s!r}, which the observation lacks")
            parts.append(np.asarray(obs[s], np.float64).reshape(self.num_envs, -1))
        return np.concatenate(parts, axis=1)  # (N, D)

    def statistics(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """Advance one step and return the statistics ``(N, S)`` (0 where an env's history
        is too short for one)."""
        x = self._concat(obs)
        first = self.age == 0
        self._lag[first] = x[first, None]
        lag1 = self._lag[:, 0]
        inst = (self.age >= 2)[:, None]
        win = (self.age >= self.cfg.window + 1)[:, None]
        stat = np.concatenate(self._predicted(x, inst, win) + self._physics(x, first, inst, win),
                              axis=1)
        if self.cfg.explain:
            stat = self._explained(stat, inst, win)
        if self.cfg.contact_model:
            stat = np.concatenate([stat, self._contact(x, first, lag1, stat, win)], axis=1)
        stat[self.age < self.cfg.warmup] = 0.0
        self._lag[:, 1], self._lag[:, 0] = lag1, x
        self.age += 1
        self._t += 1
        return stat

    def _predicted(self, x: np.ndarray, inst: np.ndarray, win: np.ndarray) -> list[np.ndarray]:
        """The predictor statistics: ``z``, ``z_mean``, ``z_sq`` (and ``z2``, ``z2_sq``)."""
        lag1, lag2 = self._lag[:, 0], self._lag[:, 1]
        s, n, i = self.stats, self.cfg.window, self._t
        feats = (np.concatenate([x, lag1, lag2], axis=1) - s["feat_mean"]) / s["feat_std"]
        z = (x[:, :P] - feats @ s["weight"] - s["bias"]) / s["z_std"]  # (N, P)
        self._zbuf[:, i % n] = z
        self._rbuf[:, i % (n + 2)] = z
        out = [np.abs(z) * inst, np.abs(self._zbuf.mean(1)) * win,
               (self._zbuf ** 2).mean(1) * win]
        if self.cfg.two_sided:
            z2 = (lag1[:, :P] - feats @ s["weight2"] - s["bias2"]) / s["z2_std"]
            self._z2buf[:, i % n] = z2
            out += [np.abs(z2) * inst, (self._z2buf ** 2).mean(1) * win]
        return out

    def _influences(self) -> np.ndarray:
        """``A[m, l, k, d]``: how much channel k's residual at t-l (in its z units) moves
        predictor m's z-score of channel d (m = 0: ``z``, 1: ``z2``); self and encoder
        partner excluded."""
        s, std = self.stats, self.stats["feat_std"]
        kinds = [("weight", "z_std")] + ([("weight2", "z2_std")] if self.cfg.two_sided else [])
        own = np.eye(P, dtype=bool) | np.eye(P, dtype=bool)[encoder_partner(np.arange(P))]
        out = np.zeros((len(kinds), 3, P, P))
        for m, (w, zs) in enumerate(kinds):
            for lag in range(3):
                rows = slice(lag * D, lag * D + P)
                a = s[w][rows] / std[rows, None] * s["z_std"][:, None] / s[zs][None]
                out[m, lag] = np.where(own, 0.0, a)
        return out

    def _explained(self, stat: np.ndarray, inst: np.ndarray, win: np.ndarray) -> np.ndarray:
        """``stat`` with each predictor statistic the smaller of itself and its value once
        the suspects' residuals (channels flagged or accused now) are taken out."""
        k = stat.shape[1]  # the contact statistics come later
        suspect = self.flags | ((stat > self.stats["threshold"][:k]) @ self.accuse[:k] > 0)
        rows = suspect.any(1)
        if not rows.any():
            return stat
        n, i, a = self.cfg.window, self._t, self._influence
        order = (i - np.arange(n + 2)[::-1]) % (n + 2)  # oldest first
        hist = self._rbuf[rows][:, order]  # (R, n + 2, P)
        sus = hist * suspect[rows][:, None]

        def taken_out(m: int) -> np.ndarray:  # (R, n, P): the correction over the window
            return sum(sus[:, 2 - lag:n + 2 - lag] @ a[m, lag] for lag in range(3))

        zc = hist[:, 2:] + taken_out(0)
        inst, win = inst[rows], win[rows]
        new = [np.abs(zc[:, -1]) * inst, np.abs(zc.mean(1)) * win, (zc ** 2).mean(1) * win]
        if self.cfg.two_sided:
            z2 = self._z2buf[rows][:, (i - np.arange(n)[::-1]) % n] + taken_out(1)
            new += [np.abs(z2[:, -1]) * inst, (z2 ** 2).mean(1) * win]
        new = np.concatenate(new, axis=1)
        stat = stat.copy()
        stat[rows, :new.shape[1]] = np.minimum(stat[rows, :new.shape[1]], new)
        return stat

    def _physics(self, x: np.ndarray, first: np.ndarray, inst: np.ndarray,
                 win: np.ndarray) -> list[np.ndarray]:
        """The physics statistics: ``enc``, ``enc_mean``, ``repeat``, ``gnorm``, ``imu``,
        ``binary``."""
        lag1, s = self._lag[:, 0], self.stats
        q, qd = slice(0, NJ), slice(NJ, 2 * NJ)
        e = (x[:, q] - lag1[:, q] - self.dt * (x[:, qd] + lag1[:, qd]) / 2) / s["enc_std"]
        n, k, i = self.cfg.window, self.cfg.imu_window, self._t
        self._ebuf[:, i % n] = e
        g = x[:, OFFSET["gravity"]:OFFSET["gravity"] + 3]
        w = x[:, OFFSET["ang_vel"]:OFFSET["ang_vel"] + 3]
        self._cbuf[:, i % (k + 1)] = np.cross(w, g)
        self._gbuf[:, i % (k + 1)] = g
        self._wbuf[:, i % (k + 1)] = w
        old = self._gbuf[:, (i + 1) % (k + 1)]  # g_{t-k}
        c = self._cbuf
        integral = self.dt * (c.sum(1) - (c[:, (i + 1) % (k + 1)] + c[:, i % (k + 1)]) / 2)
        imu = np.linalg.norm(g - old + integral, axis=1, keepdims=True)
        gnorm = np.abs(np.linalg.norm(g, axis=1, keepdims=True) - 1.0)
        same = x[:, self._nb] == lag1[:, self._nb]
        self._rep = np.where(same & ~first[:, None], self._rep + 1, 0.0)
        fc = x[:, OFFSET["foot_contact"]:OFFSET["foot_contact"] + 4]
        binary = np.minimum(np.abs(fc), np.abs(fc - 1.0))
        return [np.abs(e) * inst, np.abs(self._ebuf.mean(1)) * win, self._rep, gnorm,
                imu * (self.age >= k + 1)[:, None], binary]

    def _contact(self, x: np.ndarray, first: np.ndarray, lag1: np.ndarray, stat: np.ndarray,
                 win: np.ndarray) -> np.ndarray:
        """The ``contact`` statistics (N, 4); ``stat`` holds every other statistic."""
        s = self.stats
        self._clag[:, 1:] = self._clag[:, :-1].copy()
        self._clag[:, 0] = x[:, CONTACT_INPUTS]
        self._clag[first] = x[first][:, None, CONTACT_INPUTS]  # a new episode repeats its first
        p = contact_probability(s, self._clag.reshape(self.num_envs, -1))
        seen = lag1[:, CONTACTS] > 0.5
        u = -np.log(np.clip(np.where(seen, p, 1.0 - p), 1e-6, 1.0))
        self._ubuf[:, self._t % self.cfg.window] = u
        other = NOT_CONTACTS
        accused = (stat > s["threshold"][:stat.shape[1]]) @ self.accuse[:stat.shape[1]]
        trusted = ~(self.flags[:, other].any(1) | (accused[:, other] > 0).any(1))
        return self._ubuf.mean(1) * (win & trusted[:, None])

    def update(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """One control step: ``obs[s]`` is ``(N, dim_s)`` for every sensor in
        ``INPUT_SENSORS``. Returns the latched flags ``{sensor: (N, dim) bool}`` for the
        guarded sensors (True = faulty, remove it)."""
        self.flags |= self.accused(self.statistics(obs))
        return self.flagged()

    def accused(self, stat: np.ndarray) -> np.ndarray:
        """Channels ``(N, P)`` the statistics ``stat`` (N, S) of the step just taken
        accuse (call once per :meth:`statistics`: the IMU's attribution keeps state)."""
        fire = stat > self.stats["threshold"]
        if not self.cfg.imu_attribution:
            return (fire @ self.accuse) > 0
        imu = fire[:, self._imu_row].copy()
        fire[:, self._imu_row] = False
        out = (fire @ self.accuse) > 0
        return out | self._imu_blame(imu, out)

    def flagged(self) -> dict[str, np.ndarray]:
        return {s: self.flags[:, OFFSET[s]:OFFSET[s] + registry.get(s).dim].copy()
                for s in self.sensors}


def contact_probability(s: dict[str, np.ndarray], feats: np.ndarray) -> np.ndarray:
    """The contact network: the probability (N, 4) of each foot's contact one step back
    from the other inputs of the last ``contact_lags`` steps (N, lags x 45), newest first."""
    def gelu(v: np.ndarray) -> np.ndarray:  # torch's GELU(approximate="tanh")
        return 0.5 * v * (1.0 + np.tanh(0.7978845608028654 * (v + 0.044715 * v ** 3)))

    h = gelu((feats - s["contact_mean"]) / s["contact_std"] @ s["contact_w0"] + s["contact_b0"])
    h = gelu(h @ s["contact_w1"] + s["contact_b1"])
    return 1.0 / (1.0 + np.exp(-(h @ s["contact_w2"] + s["contact_b2"])))

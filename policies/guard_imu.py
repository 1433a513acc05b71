"""The guard's IMU rules (docs/faults.md, "The guard"): which half of the IMU lies when the
gyro disagrees with the gravity vector's change, and, once the gravity vector alone is
flagged, its repair: the last trusted gravity vector carried forward by the gyro
(``dg/dt = -w x g`` in the base frame), fed to the student in place of the lying reading.

A mixin of :class:`msta.policies.guard.SensorGuard`; it reads the guard's ring buffers of the
gravity vector, the gyro and their product over the last ``imu_window`` + 1 steps. Numpy
only.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from msta.data.sensors import PHYSICAL_SENSORS, total_dim

_AT = {s: total_dim(PHYSICAL_SENSORS[:i]) for i, s in enumerate(PHYSICAL_SENSORS)}
GYRO = np.arange(_AT["ang_vel"], _AT["ang_vel"] + 3)
GRAVITY = np.arange(_AT["gravity"], _AT["gravity"] + 3)


def carry_gravity(g: np.ndarray, w0: np.ndarray, w1: np.ndarray, dt: float) -> np.ndarray:
    """Vectors (N, 3) in the base frame one step on: rotated by ``-dt`` times the gyro's mean
    of the two steps (``dg/dt = -w x g``; Rodrigues' formula, so norms are kept)."""
    phi = -dt * (w0 + w1) / 2
    angle = np.linalg.norm(phi, axis=1, keepdims=True)
    k = phi / np.maximum(angle, 1e-12)
    cos, sin = np.cos(angle), np.sin(angle)
    return g * cos + np.cross(k, g) * sin + k * (k * g).sum(1, keepdims=True) * (1 - cos)


class ImuRules:
    """The IMU's attribution and the gravity repair (mixed into SensorGuard)."""

    def _imu_blame(self, fire: np.ndarray, others: np.ndarray) -> np.ndarray:
        """The channels the IMU check blames (N, P): see ``imu_attribution``."""
        row = self.accuse[self._imu_row] > 0
        gyro, grav = GYRO[row[GYRO]], GRAVITY[row[GRAVITY]]
        sus = others | self.flags
        sus_gyro, sus_grav = sus[:, gyro].any(1), sus[:, grav].any(1)
        self._pending[fire & (self._pending < 0)] = 0
        active = self._pending >= 0
        by_shape = active & ~sus_gyro & ~sus_grav & (self._pending >= self.cfg.imu_delay)
        jump = by_shape & (self._jump_share() >= self.cfg.imu_jump) if by_shape.any() \
            else by_shape
        blame = np.zeros_like(others)
        blame[np.ix_((active & sus_gyro & ~sus_grav) | (by_shape & ~jump), gyro)] = True
        blame[np.ix_((active & sus_grav & ~sus_gyro) | (by_shape & jump), grav)] = True
        decided = by_shape | (active & (sus_gyro | sus_grav))
        self._pending[decided] = -1
        self._pending[active & ~decided] += 1
        return blame

    def _ring_order(self) -> np.ndarray:
        """Ring positions of the last ``imu_window`` + 1 steps, oldest first."""
        k, t = self.cfg.imu_window, self._t - 1  # the step statistics() just took
        return (t - np.arange(k + 1)[::-1]) % (k + 1)

    def _jump_share(self) -> np.ndarray:
        """(N,): the largest share of the IMU residual carried by one of its steps (the
        window's residual is the sum of its one-step residuals)."""
        order = self._ring_order()
        g, c = self._gbuf[:, order], self._cbuf[:, order]
        e = g[:, 1:] - g[:, :-1] + self.dt * (c[:, 1:] + c[:, :-1]) / 2  # (N, k, 3)
        r = e.sum(1)
        norm = np.maximum(np.linalg.norm(r, axis=1), 1e-12)
        return np.einsum("nkd,nd->nk", e, r).max(1) / norm ** 2

    @property
    def repairs(self) -> bool:
        """Whether :meth:`repair` can replace a flagged gravity vector (``repair_gravity``
        and both halves of the IMU guarded)."""
        return bool(self.cfg.repair_gravity) and {"gravity", "ang_vel"} <= set(self.sensors)

    def repair(self, obs: Mapping[str, np.ndarray]) -> tuple[dict, dict[str, np.ndarray]]:
        """After :meth:`update` on ``obs``: ``(obs, removed)``, the observation with the
        gravity vector replaced on the robots whose gravity vector (and not the gyro) is
        flagged, and the flags without those repaired channels: what to remove. The
        estimate starts from the mean of the ring's older readings (10 to 5 steps before
        the flag, before most faults began), each carried forward by the gyro."""
        flags = self.flagged()
        if not self.repairs:
            return dict(obs), flags
        on = self.flags[:, GRAVITY].any(1) & ~self.flags[:, GYRO].any(1)
        order, dt = self._ring_order(), self.dt
        g, w = self._gbuf[:, order], self._wbuf[:, order]  # (N, k + 1, 3), oldest first
        start = np.flatnonzero(on & ~self._repairing)
        if len(start):  # the mean of the older half of the ring's readings, carried to now
            k = self.cfg.imu_window
            first = k - np.minimum(self.age[start] - 1, k)  # oldest ring step of this episode
            use = np.arange(k + 1)[None] <= np.maximum(first, k // 2)[:, None]  # (R, k + 1)
            use &= np.arange(k + 1)[None] >= first[:, None]
            acc = g[start, 0] * use[:, :1]
            for j in range(1, k + 1):
                acc = carry_gravity(acc, w[start, j - 1], w[start, j], dt) + g[start, j] * use[:, j:j + 1]
            self._ghat[start] = acc / np.maximum(np.linalg.norm(acc, axis=1, keepdims=True), 1e-12)
        cont = np.flatnonzero(on & self._repairing)
        if len(cont):
            self._ghat[cont] = carry_gravity(self._ghat[cont], w[cont, -2], w[cont, -1], dt)
        self._repairing = on
        out = dict(obs)
        if on.any():
            grav = np.array(obs["gravity"], copy=True)
            grav[on] = self._ghat[on].astype(grav.dtype)
            out["gravity"] = grav
            flags["gravity"][on] = False
        return out, flags

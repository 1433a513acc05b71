"""The default teacher: a model-based trotting controller with privileged information.

No training. Every control step, per environment (batched in numpy):

1. A gait clock advances; legs FL+RR and FR+RL alternate (trot) with duty factor ``duty``.
2. Feet are planned in the *horizontal frame* H: origin at the base, yaw-aligned, z up.
   Stance feet slide backward at the commanded planar and yaw velocity (this drives the
   body), at a height that puts the base ``body_height`` above the mean ground under the
   body (from the privileged height scan). Swing feet go from lift-off to a Raibert
   touchdown point ``hip + v T_stance / 2 + k (v - v_cmd)`` (privileged true velocity),
   lifted ``swing_height`` above the highest ground on the way (height scan); stance
   feet that find no ground keep extending (foot contact). A stance foot's ground height
   is read under the *measured* foot (forward kinematics of ``joint_pos`` and the
   attitude), not under the planned one, which near a step edge can be on the other step.
   On rough ground (the scan's largest second difference near the base: steps, obstacles,
   rough slopes; zero on planes and slopes) the velocity reference is capped lower and
   swing feet lift higher.
3. H-frame targets go to the base frame through a roll/pitch rotation: for stance feet the
   desired attitude pushed against the measured error (so the legs torque the body
   level), for swing feet the true attitude (so they land where planned); analytic
   inverse kinematics gives joint angles. The internal velocity reference is rate-limited
   and capped (``max_speed``), which trades top-speed tracking for survival.
4. The soft position servo (Kp = 30, Kd = 0.7) sags under load and lags in motion, so the
   weight carried by the stance legs (plus velocity feedback forces) is mapped through
   the leg Jacobians to torques, the damping torque of the planned joint velocity is
   added, and the sum enters the target as ``tau / Kp`` (with the privileged
   motor-strength and Kp/Kd factors).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msta.data.robot import A1, ACTION_SCALE, CONTROL_DT, KP, RobotDescription
from msta.data.sensors import DYNAMICS_NAMES
from msta.policies.teacher.base import check_obs, register_teacher, teacher_view
from msta.policies.teacher.gait_kinematics import foot_jacobian, leg_ik
from msta.policies.teacher.gait_state import GaitState, rot_rp
from msta.policies.teacher.gait_terrain import ground_at, ground_max_along

GRAVITY = 9.81
#: Trot: diagonal pairs FL+RR and FR+RL half a cycle apart.
TROT_OFFSETS = (0.0, 0.5, 0.5, 0.0)
_DYN = {name: i for i, name in enumerate(DYNAMICS_NAMES)}
#: Where stance feet read their ground height (GaitConfig.stance_ground).
STANCE_GROUNDS = ("actual", "planned")


@dataclass
class GaitConfig:
    """Gait controller parameters (draccus-compatible).

    Args:
        period: s, gait cycle duration.
        duty: fraction of the cycle a foot is on the ground.
        follow_gap: m, with ``GaitTeacher.follow_robot`` the furthest a stance foot's plan may
            lead its measured position (0: the plan restarts at the measured foot). The
            default 0.08 is about the lead of the plan when the teacher drives itself (servo
            lag), so it leaves the teacher's own walk nearly unchanged.
        phase_offsets: per-leg phase offsets (FL, FR, RL, RR); default trot.
        body_height: m, base height above the mean ground under the body.
        swing_height: m, foot clearance above the highest ground along the swing.
        swing_lift_frac: fraction of the swing spent lifting before moving forward much.
        swing_lead: s, swing targets run this far ahead of the clock (servo lag).
        stance_width: m, extra lateral offset of the feet outward of the thigh joints.
        raibert_gain: s, touchdown shift per m/s of velocity error (v - v_cmd), (x, y).
            Lateral 0.1: 0.2 fed the trot's own sideways sway back into the footholds and
            rolled the robot over (flat, randomization on: 91.5 % -> 97.5 % survival).
        max_step: m, cap on the touchdown offset from the nominal foothold (per axis).
        stance_ground: where a stance foot's ground height is read: "actual" (the scan
            under the measured foot, from joint angles and attitude) or "planned" (under
            the planned foot, which near an edge can be a step away from the real one:
            stairs up L0-2 survival 50 % instead of 74 %).
        velocity_gain: feedback of the velocity error into the stance sweep velocity (x, y).
        yaw_gain: feedback of the yaw-rate error into the stance sweep yaw rate.
        max_speed: (vx, vy, wz) caps of the internal velocity reference (m/s, rad/s).
        rough_range: m, terrain roughness (largest second difference of the height scan
            within 0.6 m x 0.4 m of the base; 0 on planes and slopes, the riser height on
            stairs) over which the gait blends from its flat-ground settings to the rough
            ones below.
        rough_max_speed: (vx, vy, wz) caps of the velocity reference on rough ground.
        rough_swing_height: m, swing clearance on rough ground.
        max_accel: m/s^2, the internal velocity reference follows the command at most
            this fast (and yaw rate at ``2 * max_accel`` rad/s^2).
        force_velocity_gain: N per m/s of planar velocity error, as stance forces (x, y).
        max_velocity_error: m/s, cap of the velocity error fed to the two terms above.
        height_gain, height_damping: N/m and N s/m vertical feedback forces.
        attitude_gain: extra (roll, pitch) stiffness: feet are placed as if the body were
            tilted ``attitude_gain`` times its attitude error the other way.
        attitude_damping: s, the same for (roll, pitch) rates.
        max_attitude_correction: rad, cap on that attitude feedback.
        moment_gain, moment_damping: N m/rad and N m s/rad roll/pitch feedback moments
            realised by stance forces.
        slope_follow: fraction of the ground slope (roll and pitch) the body tilts along.
        reach_rate: m/s, how fast a stance foot without ground contact extends downward
            (slow enough that a one-step-late contact signal does not push a landed foot
            hard: 1.0 lost 2 points of flat survival under observation latency).
        max_reach: m, cap on that extension.
        mass: kg, nominal robot mass (the privileged added mass is added).
        kp: nominal position gain of the servo.
        kd: nominal damping gain of the servo plus the joints' passive damping; the
            damping torque of the planned joint velocity is pre-compensated.
        damping_comp: fraction of that damping torque compensated.
        max_joint_speed: rad/s, cap on the planned joint velocity used for compensation.
        action_scale: joint target = default pose + action_scale * action.
        dt: s, control period.
    """

    period: float = 0.24
    duty: float = 0.65
    follow_gap: float = 0.08
    phase_offsets: tuple[float, float, float, float] = TROT_OFFSETS
    body_height: float = 0.28
    swing_height: float = 0.07
    swing_lift_frac: float = 0.08
    swing_lead: float = 0.02
    stance_width: float = 0.0
    raibert_gain: tuple[float, float] = (0.2, 0.1)
    max_step: float = 0.2
    stance_ground: str = "actual"
    velocity_gain: tuple[float, float] = (1.0, 0.3)
    yaw_gain: float = 1.2
    max_speed: tuple[float, float, float] = (1.0, 0.6, 1.0)
    rough_range: tuple[float, float] = (0.02, 0.035)
    rough_max_speed: tuple[float, float, float] = (0.6, 0.4, 1.0)
    rough_swing_height: float = 0.1
    max_accel: float = 2.4
    force_velocity_gain: tuple[float, float] = (100.0, 30.0)
    max_velocity_error: float = 0.25
    height_gain: float = 0.0
    height_damping: float = 0.0
    attitude_gain: tuple[float, float] = (1.0, 0.8)
    attitude_damping: tuple[float, float] = (0.02, 0.02)
    max_attitude_correction: float = 0.25
    moment_gain: float = 0.0
    moment_damping: float = 0.0
    slope_follow: float = 0.0
    reach_rate: float = 0.5
    max_reach: float = 0.08
    mass: float = 12.453
    kp: float = KP
    kd: float = 0.8
    damping_comp: float = 0.35
    max_joint_speed: float = 15.0
    action_scale: float = ACTION_SCALE
    dt: float = CONTROL_DT

    def __post_init__(self) -> None:
        self.phase_offsets = tuple(float(v) for v in self.phase_offsets)
        for name in ("max_speed", "rough_max_speed"):
            value = tuple(float(v) for v in getattr(self, name))
            if len(value) != 3 or min(value) <= 0:
                raise ValueError(f"{name}={value} needs three positive values")
            setattr(self, name, value)
        for name in ("raibert_gain", "velocity_gain", "force_velocity_gain", "attitude_gain",
                     "attitude_damping", "rough_range"):
            value = tuple(float(v) for v in getattr(self, name))
            if len(value) != 2:
                raise ValueError(f"{name}={value} needs two values")
            setattr(self, name, value)
        if self.stance_ground not in STANCE_GROUNDS:
            raise ValueError(f"stance_ground={self.stance_ground!r}: use one of {STANCE_GROUNDS}")
        if len(self.phase_offsets) != 4:
            raise ValueError(f"phase_offsets={self.phase_offsets} needs one value per leg")
        if not self.follow_gap >= 0.0:
            raise ValueError(f"follow_gap={self.follow_gap} must be >= 0")
        if not 0.0 < self.duty < 1.0:
            raise ValueError(f"duty={self.duty} must be in (0, 1)")
        for name in ("period", "body_height", "mass", "kp", "action_scale", "dt"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}={getattr(self, name)} must be > 0")
        if not 0.0 <= self.swing_lift_frac < 0.5:
            raise ValueError(f"swing_lift_frac={self.swing_lift_frac} must be in [0, 0.5)")

    @classmethod
    def for_robot(cls, robot: RobotDescription) -> GaitConfig:
        """The defaults with the robot's servo gain, action scale and control period (on
        the A1 exactly the defaults).

        Args:
            robot: the robot the controller drives, with the control numbers in force.
        """
        return cls(kp=robot.kp, action_scale=robot.action_scale, dt=robot.control_dt)


def _smooth(s: np.ndarray) -> np.ndarray:
    s = np.clip(s, 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


@register_teacher("gait")
class GaitTeacher:
    """Trotting controller on privileged state (see the module docstring).

    Args:
        config: controller parameters; default :meth:`GaitConfig.for_robot` of ``robot``
            (on the A1 the defaults, which walk all terrains).
        robot: the robot it drives (leg geometry, default pose, foot radius; None: the A1),
            with the control numbers in force. It reads ``foot_contact``, or on a robot
            that offers none the simulator's ``true_contact`` (:func:`teacher_view`).

    Attributes:
        follow_robot: False (default) when the teacher drives: the stance feet slide along
            its own plan. True when it labels states another policy drives (msta-correct):
            each step the stance feet's planned positions restart from the measured ones
            (forward kinematics of ``joint_pos`` and the attitude), so the labels do not pull
            the feet back to a plan the robot never followed. The gait clock keeps running.
    """

    name = "gait"
    sensors: tuple[str, ...] = ("command", "foot_contact", "joint_pos", "base_lin_vel",
                                "base_ang_vel", "orientation", "height_scan", "dynamics")

    def __init__(self, config: GaitConfig | None = None,
                 robot: RobotDescription | None = None) -> None:
        self.robot = robot = robot or A1
        self.cfg = config or GaitConfig.for_robot(robot)
        self._default_pose = np.array(robot.default_pose, dtype=np.float64)   # (joints,)
        self._n = 0
        self.phase = np.zeros(0)
        self.feet = np.zeros((0, 4, 3))      # current H-frame foot targets
        self.liftoff = np.zeros((0, 4, 3))   # H-frame foot position at lift-off
        self.stance = np.zeros((0, 4), dtype=bool)
        self.fresh = np.zeros(0, dtype=bool)
        self.q_prev = np.zeros((0, robot.num_joints))
        self.reach = np.zeros((0, 4))          # extra downward reach of stance feet
        self.ref_cmd = np.zeros((0, 3))      # rate-limited command
        self.caution = np.zeros((0, 1))      # 0 flat-ground gait .. 1 rough-ground gait
        self.follow_robot = False
        hips = np.array(robot.hip_offsets, dtype=np.float64)               # (4, 2)
        thigh_y = np.array(robot.thigh_offset_y, dtype=np.float64)         # (4,)
        nominal = np.column_stack([hips[:, 0], hips[:, 1] + thigh_y
                                   + np.sign(thigh_y) * self.cfg.stance_width])
        self.nominal_xy = nominal                      # (4, 2)

    # ------------------------------------------------------------------ protocol
    def reset(self, ids: np.ndarray) -> None:
        """Restart the gait of environments ``ids`` (their next ``act`` re-initializes)."""
        ids = np.asarray(ids, dtype=np.int64)
        ids = ids[ids < self._n]  # a new batch size re-initializes every env in act()
        if self._n and len(ids):
            self.fresh[ids] = True

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """(N, 12) actions (offsets from the default pose in units of ``action_scale``)."""
        obs = teacher_view(obs)
        n = check_obs(self, obs)
        if n != self._n:
            self._allocate(n)
        cfg = self.cfg
        st = GaitState.from_obs(obs, self.robot, cfg.slope_follow)
        self.just_reset = self.fresh.copy()
        if self.fresh.any():
            self._init_feet(np.flatnonzero(self.fresh), st)
            self.fresh[:] = False
        if self.follow_robot:  # labelling another policy: keep the plan near the feet
            self._follow(st)
        step = cfg.max_accel * cfg.dt * np.array([1.0, 1.0, 2.0])
        lo, hi = cfg.rough_range
        self.caution = np.clip((st.roughness - lo) / max(hi - lo, 1e-9), 0.0, 1.0)[:, None]
        lim = (1 - self.caution) * np.asarray(cfg.max_speed) + self.caution * np.asarray(
            cfg.rough_max_speed)
        self.ref_cmd += np.clip(np.clip(st.cmd, -lim, lim) - self.ref_cmd, -step, step)
        st.cmd = self.ref_cmd.copy()
        leg_phase = (self.phase[:, None] + np.asarray(cfg.phase_offsets)[None]) % 1.0
        stance = leg_phase < cfg.duty
        self._update_stance(st, stance)
        self._update_swing(st, stance, leg_phase)
        self.stance = stance
        self._update_reach(obs["foot_contact"], stance, leg_phase)
        weight = self._stance_weight(stance, leg_phase)
        q_des, jac, q_plan = self._joint_targets(st, weight)
        tau = self._feedforward(st, weight, jac)
        strength = st.dyn[:, _DYN["motor_strength"]]
        kp = cfg.kp * st.dyn[:, _DYN["kp_factor"]] * strength
        kd = cfg.kd * st.dyn[:, _DYN["kd_factor"]] * strength
        # Planned joint velocity (attitude feedback excluded, so it cannot pump energy).
        qd = np.clip((q_plan - self.q_prev) / cfg.dt, -cfg.max_joint_speed, cfg.max_joint_speed)
        qd[self.just_reset] = 0.0
        self.q_prev = q_plan
        tau = tau + cfg.damping_comp * kd[:, None] * qd
        target = q_des + tau / kp[:, None]
        self.phase = (self.phase + cfg.dt / cfg.period) % 1.0
        return ((target - self._default_pose[None]) / cfg.action_scale).astype(np.float32)

    # ------------------------------------------------------------------ internals
    def _allocate(self, n: int) -> None:
        self._n = n
        self.phase = np.zeros(n)
        self.feet = np.zeros((n, 4, 3))
        self.liftoff = np.zeros((n, 4, 3))
        self.stance = np.ones((n, 4), dtype=bool)
        self.fresh = np.ones(n, dtype=bool)
        self.q_prev = np.tile(self._default_pose, (n, 1))
        self.reach = np.zeros((n, 4))
        self.ref_cmd = np.zeros((n, 3))

    def _init_feet(self, ids: np.ndarray, st: GaitState) -> None:
        self.phase[ids] = 0.0
        self.reach[ids] = 0.0
        self.ref_cmd[ids] = 0.0
        xy = np.broadcast_to(self.nominal_xy, (len(ids), 4, 2))
        z = ground_at(st.grid[ids], xy) - st.ref[ids, None] - self.cfg.body_height + self.robot.foot_radius
        self.feet[ids] = np.concatenate([xy, z[..., None]], axis=-1)
        self.liftoff[ids] = self.feet[ids]
        self.stance[ids] = True

    def _follow(self, st: GaitState) -> None:
        """Stance feet's planned xy pulled to within ``follow_gap`` of the measured feet."""
        actual = st.feet_actual[..., :2]                                   # (N, 4, 2)
        lead = self.feet[..., :2] - actual
        dist = np.linalg.norm(lead, axis=-1, keepdims=True)               # (N, 4, 1)
        gap = self.cfg.follow_gap
        pulled = actual + lead * np.minimum(1.0, gap / np.maximum(dist, 1e-9))
        self.feet[..., :2] = np.where(self.stance[..., None], pulled, self.feet[..., :2])

    def _sweep_velocity(self, st: GaitState) -> tuple[np.ndarray, np.ndarray]:
        """Planar velocity (N, 2) and yaw rate (N,) the stance feet move the body at."""
        cfg = self.cfg
        err = np.clip(st.cmd[:, :2] - st.v[:, :2], -cfg.max_velocity_error, cfg.max_velocity_error)
        v = st.cmd[:, :2] + np.asarray(cfg.velocity_gain) * err
        return v, st.cmd[:, 2] + cfg.yaw_gain * (st.cmd[:, 2] - st.w[:, 2])

    def _update_stance(self, st: GaitState, stance: np.ndarray) -> None:
        cfg = self.cfg
        v, wz = self._sweep_velocity(st)
        p = self.feet[..., :2]
        dp = v[:, None, :] + wz[:, None, None] * np.stack([-p[..., 1], p[..., 0]], axis=-1)
        new_xy = p - cfg.dt * dp
        g = ground_at(st.grid, st.feet_actual[..., :2] if cfg.stance_ground == "actual" else new_xy)
        z = g - st.ref[:, None] - cfg.body_height + self.robot.foot_radius
        upd = np.concatenate([new_xy, z[..., None]], axis=-1)
        self.feet = np.where(stance[..., None], upd, self.feet)
        lifting = ~stance & self.stance
        self.liftoff = np.where(lifting[..., None], self.feet, self.liftoff)

    def _touchdown(self, st: GaitState) -> np.ndarray:
        """Raibert touchdown points (N, 4, 2) in the H frame."""
        cfg = self.cfg
        t_stance = cfg.duty * cfg.period
        hips = np.broadcast_to(self.nominal_xy, (st.n, 4, 2))
        wz = st.cmd[:, 2][:, None]
        v_hip = st.cmd[:, None, :2] + wz[..., None] * np.stack([-hips[..., 1], hips[..., 0]], -1)
        err = st.v[:, None, :2] - st.cmd[:, None, :2]
        off = v_hip * t_stance / 2 + np.asarray(cfg.raibert_gain) * err
        off = np.clip(off, -cfg.max_step, cfg.max_step)
        return hips + off

    def _update_swing(self, st: GaitState, stance: np.ndarray, leg_phase: np.ndarray) -> None:
        cfg = self.cfg
        t_swing = cfg.period * (1.0 - cfg.duty)
        s = np.clip((leg_phase - cfg.duty) / (1.0 - cfg.duty) + (cfg.dt + cfg.swing_lead) / t_swing,
                    0.0, 1.0)
        td = self._touchdown(st)
        lift_xy = self.liftoff[..., :2]
        u = _smooth((s - cfg.swing_lift_frac) / (1.0 - 2 * cfg.swing_lift_frac))
        xy = lift_xy + (td - lift_xy) * u[..., None]
        g_here = ground_at(st.grid, xy)
        g_ahead = ground_max_along(st.dilated, xy, td)
        g_td = ground_at(st.grid, td)
        # Rise over the highest ground ahead, come down onto the touchdown ground.
        height = cfg.swing_height + self.caution * (cfg.rough_swing_height - cfg.swing_height)
        clear = np.maximum(g_here, g_ahead) + height * np.sin(np.pi * s) ** 0.5   # s in [0, 1]
        landing = _smooth((s - 0.75) / 0.25)
        zg = (1 - landing) * clear + landing * g_td
        z = zg - st.ref[:, None] - cfg.body_height + self.robot.foot_radius
        sw = np.concatenate([xy, z[..., None]], axis=-1)
        self.feet = np.where(stance[..., None], self.feet, sw)

    def _update_reach(self, contact: np.ndarray, stance: np.ndarray, leg_phase: np.ndarray
                      ) -> None:
        """Stance feet that find no ground keep extending downward (late touchdown,
        unexpected drop); the extra reach fades once they touch."""
        cfg = self.cfg
        searching = stance & (contact < 0.5) & (leg_phase > 0.1 * cfg.duty)
        self.reach = np.where(searching, np.minimum(self.reach + cfg.reach_rate * cfg.dt,
                                                    cfg.max_reach), self.reach * 0.8)
        self.reach[~stance] = 0.0

    def _stance_weight(self, stance: np.ndarray, leg_phase: np.ndarray) -> np.ndarray:
        """(N, 4) in [0, 1]: 1 in mid-stance, ramping at touchdown and lift-off, 0 in swing."""
        ramp = 0.12
        sph = leg_phase / self.cfg.duty
        w = np.where(stance, np.minimum(_smooth(sph / ramp), _smooth((1 - sph) / ramp)), 0.0)
        return np.maximum(w, 1e-3 * stance)

    def _joint_targets(self, st: GaitState, weight: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint angles (N, 12), foot Jacobians and the joint angles without attitude
        feedback (N, 12) for the H-frame feet.

        H -> base frame is p_b = R^T p_h. Stance feet use the *commanded* roll/pitch
        (the desired attitude pushed further against the error), so the legs torque the
        body back; swing feet use the true attitude, so they land where planned.
        """
        cfg = self.cfg
        err = st.rp - st.rp_des
        corr = -np.asarray(cfg.attitude_gain) * err - np.asarray(cfg.attitude_damping) * st.w[:, :2]
        rp_cmd = st.rp_des + np.clip(corr, -cfg.max_attitude_correction, cfg.max_attitude_correction)
        feet = self.feet.copy()
        feet[..., 2] -= self.reach
        feet_cmd = np.einsum("nji,nkj->nki", rot_rp(rp_cmd), feet)
        feet_true = np.einsum("nji,nkj->nki", st.rot_rp, feet)
        feet_b = weight[..., None] * feet_cmd + (1.0 - weight[..., None]) * feet_true
        q = leg_ik(feet_b, self.robot)
        feet_plan = np.einsum("nji,nkj->nki", rot_rp(st.rp_des), self.feet)
        return q, foot_jacobian(q, self.robot), leg_ik(feet_plan, self.robot)

    def _feedforward(self, st: GaitState, w: np.ndarray, jac: np.ndarray) -> np.ndarray:
        """Joint torques (N, 12) for the stance forces of a virtual-model balance law."""
        cfg = self.cfg
        share = w / np.maximum(w.sum(axis=1, keepdims=True), 1e-6)       # (N, 4)
        mass = cfg.mass + st.dyn[:, _DYN["added_mass"]]
        fz = mass * GRAVITY
        fz = fz + cfg.height_gain * (cfg.body_height - st.height) - cfg.height_damping * st.v[:, 2]
        f = np.zeros((st.n, 4, 3))
        f[..., 2] = share * fz[:, None]
        err = np.clip(st.cmd[:, :2] - st.v[:, :2], -cfg.max_velocity_error, cfg.max_velocity_error)
        fxy = np.asarray(cfg.force_velocity_gain) * err * mass[:, None] / cfg.mass
        f[..., :2] = share[..., None] * fxy[:, None, :]
        # Roll/pitch moments from vertical force differences between stance feet.
        m_rp = -cfg.moment_gain * (st.rp - st.rp_des) - cfg.moment_damping * st.w[:, :2]
        x, y = self.feet[..., 0], self.feet[..., 1]
        # moment about x: sum y_i f_i = m_roll; about y: -sum x_i f_i = m_pitch
        for axis, lever, sign in ((0, y, 1.0), (1, x, -1.0)):
            lev = lever - (share * lever).sum(axis=1, keepdims=True)
            denom = np.maximum((share * lev * lev).sum(axis=1, keepdims=True), 1e-4)
            f[..., 2] += sign * m_rp[:, axis:axis + 1] * share * lev / denom
        f_b = np.einsum("nji,nkj->nki", st.rot_rp, f)          # ground force in base frame
        tau = -np.einsum("nkij,nki->nkj", jac, f_b)
        return tau.reshape(st.n, self.robot.num_joints)


__all__ = ["GaitConfig", "GaitTeacher"]

"""Scene assembly (a robot description's MJCF + terrain heightfield); the MuJoCo side of
msta.data.robot.

What the simulator needs of a robot's MJCF (the shipped A1's ``assets/a1.xml`` is the
example; docs/robots.md): a free joint first, then the hinge joints in the description's
``joints`` order, one position actuator per joint in that order, a body ``trunk``, the
sensors in the order of ``SENS_*`` below (touch sensors ``<foot>_touch`` first, in ``feet``
order), for a robot that lists ``base_accel`` an ``accelerometer`` sensor at its IMU site
(after those), and, for the "full" collision set, thigh and calf geoms named like their joints.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from msta.data.robot import A1, RobotDescription
from msta.data.sensors import SENSORS

# Sensor layout of the MJCF (see assets/a1.xml): 4 foot touches, trunk touch,
# 4 thigh touches, 4 calf touches, 12 actuator forces.
SENS_FOOT = slice(0, 4)
SENS_TRUNK = 4
SENS_LEG_COLLISION = slice(5, 13)
SENS_TORQUE = slice(13, 25)
#: Simulator measurements read from an optional MJCF sensor (a registry ``source``), with the
#: MuJoCo sensor type that provides it at the robot's IMU site.
MJCF_SOURCES: dict[str, mujoco.mjtSensor] = {
    "accel": mujoco.mjtSensor.mjSENS_ACCELEROMETER,
}


@dataclass(frozen=True)
class StateLayout:
    """Offsets of the fields inside MuJoCo's mjSTATE_FULLPHYSICS vector."""

    size: int
    qpos: slice
    qvel: slice

    @property
    def base_pos(self) -> slice:
        return slice(self.qpos.start, self.qpos.start + 3)

    @property
    def base_quat(self) -> slice:
        return slice(self.qpos.start + 3, self.qpos.start + 7)

    @property
    def joint_pos(self) -> slice:
        return slice(self.qpos.start + 7, self.qpos.stop)

    @property
    def base_linvel(self) -> slice:
        return slice(self.qvel.start, self.qvel.start + 3)

    @property
    def base_angvel(self) -> slice:
        return slice(self.qvel.start + 3, self.qvel.start + 6)

    @property
    def joint_vel(self) -> slice:
        return slice(self.qvel.start + 6, self.qvel.stop)


def state_layout(model: mujoco.MjModel) -> StateLayout:
    """Locate qpos and qvel inside the full-physics state (time comes first)."""
    size = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    q0 = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_TIME)
    nq, nv = model.nq, model.nv
    return StateLayout(size=size, qpos=slice(q0, q0 + nq), qvel=slice(q0 + nq, q0 + nq + nv))


#: Robot collision sets: "fast" = feet, trunk, upper 10 cm of each calf (the asset as
#: written); "full" = also the whole calf and the thighs (~1.3x slower physics).
COLLISION_SETS = ("fast", "full")


def check_collision_set(name: str) -> None:
    """ValueError naming ``name`` unless it is one of ``COLLISION_SETS``."""
    if name not in COLLISION_SETS:
        raise ValueError(f"collision={name!r} is not one of {COLLISION_SETS}")


def build_model(hfield: dict | None, timestep: float | None = None, collision: str = "fast",
                robot: RobotDescription = A1) -> mujoco.MjModel:
    """Compile the robot with a terrain heightfield (or a plane when ``hfield`` is None).

    Args:
        hfield: ``Terrain.hfield_spec()``: nrow, ncol, size (rx, ry, elevation, base),
            pos (x, y, z), data (nrow, ncol) in [0, 1].
        timestep: physics step (s); None: the robot's ``sim_dt``.
        collision: one of ``COLLISION_SETS``.
        robot: the robot's description: its MJCF file, torque limits (the actuators' force
            ranges) and calf collision length.
    """
    check_collision_set(collision)
    spec = mujoco.MjSpec.from_file(str(robot.mjcf_path))
    spec.option.timestep = robot.sim_dt if timestep is None else timestep
    for actuator, limit in zip(spec.actuators, robot.joint_torque_limits, strict=False):
        actuator.forcerange = [-limit, limit]
        actuator.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
    if collision == "full":
        _full_leg_collisions(spec, robot)
    if hfield is None:
        spec.worldbody.add_geom(name="terrain", type=mujoco.mjtGeom.mjGEOM_PLANE,
                                size=[0, 0, 0.05], contype=1, conaffinity=2, material="ground")
    else:
        hf = spec.add_hfield(name="terrain", nrow=int(hfield["nrow"]), ncol=int(hfield["ncol"]),
                             size=[float(v) for v in hfield["size"]])
        hf.userdata = np.asarray(hfield["data"], dtype=np.float32).ravel().tolist()
        spec.worldbody.add_geom(name="terrain", type=mujoco.mjtGeom.mjGEOM_HFIELD,
                                hfieldname="terrain", pos=[float(v) for v in hfield["pos"]],
                                contype=1, conaffinity=2, material="ground")
        _add_surround(spec, hfield)
    _add_visuals(spec)
    model = spec.compile()
    _check_names(model, robot)
    _check_sources(model, robot)
    return model


def imu_sensor(model: mujoco.MjModel, robot: RobotDescription, source: str) -> slice | None:
    """Where in ``sensordata`` the MJCF sensor behind the measurement ``source`` (a key of
    ``MJCF_SOURCES``, e.g. ``"accel"``) at the robot's IMU site is, or None if it has none.

    Args:
        model: the compiled scene.
        robot: the robot's description (its ``imu_site``).
        source: the measurement's name.
    """
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, robot.imu_site)
    for i in range(model.nsensor):
        if (model.sensor_type[i] == MJCF_SOURCES[source] and model.sensor_objid[i] == site
                and model.sensor_objtype[i] == mujoco.mjtObj.mjOBJ_SITE):
            adr = int(model.sensor_adr[i])
            return slice(adr, adr + int(model.sensor_dim[i]))
    return None


def _check_sources(model: mujoco.MjModel, robot: RobotDescription) -> None:
    """One-line ``ValueError`` naming the MJCF if the robot lists a sensor read from an MJCF
    sensor (``MJCF_SOURCES``) its MJCF lacks at the IMU site."""
    for name in robot.sensors:
        source = SENSORS[name].source
        if source in MJCF_SOURCES and imu_sensor(model, robot, source) is None:
            kind = MJCF_SOURCES[source].name.removeprefix("mjSENS_").lower()
            raise ValueError(f"{robot.mjcf_path}: the robot {robot.name!r} lists the sensor "
                             f"{name!r}, which needs an {kind} sensor at its IMU site "
                             f"{robot.imu_site!r}; the MJCF has none")


def _full_leg_collisions(spec: mujoco.MjSpec, robot: RobotDescription) -> None:
    """Whole-calf and thigh capsules (geoms named like the thigh and calf joints) collide
    with the terrain (the "full" set)."""
    for thigh_name, calf_name in zip(robot.joints[1::3], robot.joints[2::3], strict=True):
        thigh = spec.geom(thigh_name)
        thigh.contype, thigh.conaffinity = 2, 1
        calf = spec.geom(calf_name)
        calf.fromto = [0.0, 0.0, 0.0, 0.0, 0.0, -robot.calf_collision_full]


def _add_surround(spec: mujoco.MjSpec, hfield: dict, reach: float = 100.0) -> None:
    """Ground at z = 0 around the heightfield (whose outer border is at z = 0), so a robot
    that walks off the grid keeps walking on flat ground instead of falling into the void."""
    cx, cy, _ = (float(v) for v in hfield["pos"])
    rx, ry = float(hfield["size"][0]), float(hfield["size"][1])
    half = reach / 2
    for name, pos, size in (
            ("ground_west", [cx - rx - half, cy], [half, ry + reach, 0.5]),
            ("ground_east", [cx + rx + half, cy], [half, ry + reach, 0.5]),
            ("ground_south", [cx, cy - ry - half], [rx, half, 0.5]),
            ("ground_north", [cx, cy + ry + half], [rx, half, 0.5])):
        spec.worldbody.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_BOX, pos=pos + [-0.5],
                                size=size, contype=1, conaffinity=2, material="ground")


def _add_visuals(spec: mujoco.MjSpec) -> None:
    spec.add_texture(name="grid", type=mujoco.mjtTexture.mjTEXTURE_2D,
                     builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER, rgb1=[0.45, 0.5, 0.45],
                     rgb2=[0.6, 0.65, 0.6], width=64, height=64)
    mat = spec.add_material(name="ground", texrepeat=[2, 2], texuniform=True)
    mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "grid"
    spec.worldbody.add_light(pos=[0, 0, 6], dir=[0, 0.3, -1], diffuse=[0.8, 0.8, 0.8],
                             type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL)
    spec.visual.map.znear = 0.001   # relative to the (large) terrain extent
    spec.visual.global_.offwidth = 1280
    spec.visual.global_.offheight = 720


def _check_names(model: mujoco.MjModel, robot: RobotDescription) -> None:
    """One-line ``ValueError`` naming the MJCF unless its joints after the free joint and
    its actuators' joints are exactly the description's ``joints``, and its first sensors
    the feet's touch sensors, in order (the simulator's state and sensor layout)."""
    joints = tuple(model.joint(i).name for i in range(1, model.njnt))
    driven = tuple(model.joint(int(model.actuator_trnid[i, 0])).name for i in range(model.nu))
    feet = tuple(model.sensor(i).name for i in range(min(len(robot.feet), model.nsensor)))
    for what, got, want in (("joints after the free joint", joints, robot.joints),
                            ("actuators' joints", driven, robot.joints),
                            ("first sensors", feet, tuple(f"{f}_touch" for f in robot.feet))):
        if got != want:
            raise ValueError(f"{robot.mjcf_path}: the {what} are {list(got)}; the robot "
                             f"{robot.name!r} needs {list(want)} in this order")


def default_state(model: mujoco.MjModel, robot: RobotDescription = A1) -> np.ndarray:
    """Full-physics state of the robot standing in its default pose at the origin, its
    trunk ``spawn_height`` above it.

    Args:
        model: the compiled scene (:func:`build_model`).
        robot: the robot's description (default pose, spawn height).
    """
    data = mujoco.MjData(model)
    data.qpos[:3] = (0.0, 0.0, robot.spawn_height)
    data.qpos[3:7] = (1.0, 0.0, 0.0, 0.0)
    data.qpos[7:] = robot.default_pose
    data.ctrl[:] = robot.default_pose
    mujoco.mj_forward(model, data)
    out = np.zeros(mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(model, data, out, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    return out


def joint_limits(model: mujoco.MjModel) -> np.ndarray:
    """(nu, 2) joint position limits of the actuated joints, in the robot's joint order."""
    return np.array(model.jnt_range[1:1 + model.nu], dtype=np.float64)


__all__ = [
    "COLLISION_SETS", "MJCF_SOURCES", "SENS_FOOT", "SENS_LEG_COLLISION", "SENS_TORQUE",
    "SENS_TRUNK", "StateLayout", "build_model", "check_collision_set", "default_state",
    "imu_sensor", "joint_limits", "state_layout",
]


#: The spawn ground probe's grid (m): the hips' extent is grown outward to a multiple of it.
FOOTPRINT_GRID = 0.05


def spawn_footprint(robot: RobotDescription) -> np.ndarray:
    """(legs + 1, 2) base-frame (x, y) points where a reset probes the ground under a robot
    (the spawn height counts from the highest): each leg's hip, at x its hip offset and at y
    its hip offset plus its thigh's lateral offset (the leg's plane), grown outward to the
    next multiple of ``FOOTPRINT_GRID`` (a margin for feet off the hips), and the base centre.
    The A1: (+-0.2, +-0.15) and (0, 0).

    Args:
        robot: the simulated robot's description (``hip_offsets``, ``thigh_offset_y``).
    """
    hips = np.array(robot.hip_offsets, dtype=np.float64)                    # (legs, 2)
    hips[:, 1] += np.array(robot.thigh_offset_y, dtype=np.float64)
    steps = np.ceil(np.abs(hips) / FOOTPRINT_GRID - 1e-9)  # 1e-9: an exact multiple stays
    points = np.sign(hips) * steps / round(1.0 / FOOTPRINT_GRID)  # k / 20 m: 0.15, not 3 x 0.05
    return np.vstack([points, np.zeros((1, 2))])

"""A1-class scene assembly (robot MJCF + terrain heightfield); the MuJoCo side of msta.data.robot."""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources

import mujoco
import numpy as np

from msta.data.robot import CALF_COLLISION_FULL, DEFAULT_POSE, NUM_JOINTS, SIM_DT, SPAWN_HEIGHT
from msta.data.sensors import FOOT_NAMES, JOINT_NAMES, LEGS

ASSET = "a1.xml"

# Sensor layout of the MJCF (see assets/a1.xml): 4 foot touches, trunk touch,
# 4 thigh touches, 4 calf touches, 12 actuator forces.
SENS_FOOT = slice(0, 4)
SENS_TRUNK = 4
SENS_LEG_COLLISION = slice(5, 13)
SENS_TORQUE = slice(13, 25)


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


def build_model(hfield: dict | None, timestep: float = SIM_DT,
                collision: str = "fast") -> mujoco.MjModel:
    """Compile the robot with a terrain heightfield (or a plane when ``hfield`` is None).

    Args:
        hfield: ``Terrain.hfield_spec()``: nrow, ncol, size (rx, ry, elevation, base),
            pos (x, y, z), data (nrow, ncol) in [0, 1].
        timestep: physics step (s).
        collision: one of ``COLLISION_SETS``.
    """
    check_collision_set(collision)
    xml = resources.files("msta.collect.sim").joinpath("assets", ASSET).read_text()
    spec = mujoco.MjSpec.from_string(xml)
    spec.option.timestep = timestep
    if collision == "full":
        _full_leg_collisions(spec)
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
    _check_names(model)
    return model


def _full_leg_collisions(spec: mujoco.MjSpec) -> None:
    """Whole-calf and thigh capsules collide with the terrain (the "full" set)."""
    for leg in LEGS:
        thigh = spec.geom(f"{leg}_thigh")
        thigh.contype, thigh.conaffinity = 2, 1
        calf = spec.geom(f"{leg}_calf")
        calf.fromto = [0.0, 0.0, 0.0, 0.0, 0.0, -CALF_COLLISION_FULL]


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


def _check_names(model: mujoco.MjModel) -> None:
    joints = [model.joint(i + 1).name for i in range(NUM_JOINTS)]
    if tuple(joints) != JOINT_NAMES:
        raise RuntimeError(f"robot joint order {joints} differs from the registry {JOINT_NAMES}")
    foot_sensors = [model.sensor(i).name for i in range(4)]
    if foot_sensors != [f"{f}_touch" for f in FOOT_NAMES]:
        raise RuntimeError(f"foot sensor order {foot_sensors} differs from {FOOT_NAMES}")


def default_state(model: mujoco.MjModel) -> np.ndarray:
    """Full-physics state of the robot standing in the default pose at the origin."""
    data = mujoco.MjData(model)
    data.qpos[:3] = (0.0, 0.0, SPAWN_HEIGHT)
    data.qpos[3:7] = (1.0, 0.0, 0.0, 0.0)
    data.qpos[7:] = DEFAULT_POSE
    data.ctrl[:] = DEFAULT_POSE
    mujoco.mj_forward(model, data)
    out = np.zeros(mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(model, data, out, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    return out


def joint_limits(model: mujoco.MjModel) -> np.ndarray:
    """(12, 2) joint position limits in registry order."""
    return np.array(model.jnt_range[1:13], dtype=np.float64)


__all__ = [
    "COLLISION_SETS", "SENS_FOOT", "SENS_LEG_COLLISION", "SENS_TORQUE", "SENS_TRUNK", "StateLayout",
    "build_model", "check_collision_set", "default_state", "joint_limits", "state_layout",
]

"""The robot's collision sets: which geoms can touch the terrain, and what that changes."""

import mujoco
import numpy as np
import pytest

from msta.collect.sim import robot
from msta.collect.sim.env_config import EnvConfig
from msta.data.robot import CALF_COLLISION_FULL
from msta.data.sensors import FOOT_NAMES


def _colliding(model: mujoco.MjModel) -> set[str]:
    """Names of robot geoms that can collide with the terrain (contype 1, conaffinity 2)."""
    out = set()
    for g in range(model.ngeom):
        if model.geom_bodyid[g] != 0 and model.geom_contype[g] & 2 and model.geom_conaffinity[g] & 1:
            out.add(model.geom(g).name)
    return out


def _lower_shin_contacts(collision: str) -> set[str]:
    """Names of robot geoms touching a ground plane that the front-left lower shin (15 cm
    down the calf) dips 3 mm into, with that calf pointing down-forward at ~45 degrees
    and the other legs folded up."""
    model = robot.build_model(None, collision=collision)
    data = mujoco.MjData(model)
    data.qpos[2] = 1.0
    data.qpos[3:7] = [1, 0, 0, 0]
    data.qpos[7:19] = np.tile([0.0, -1.0, -2.6], 4)          # other legs folded up
    data.qpos[7:10] = [0.0, 0.71, -1.5]                       # FL calf points down-forward
    mujoco.mj_kinematics(model, data)
    calf = model.body("FL_calf").id
    shin = data.xpos[calf] + data.xmat[calf].reshape(3, 3) @ np.array([0.0, 0.0, -0.15])
    data.qpos[2] -= shin[2] + 0.003
    mujoco.mj_forward(model, data)
    names = set()
    for c in data.contact[: data.ncon]:
        for g in (c.geom1, c.geom2):
            if model.geom_bodyid[g] != 0:
                names.add(model.geom(g).name)
    return names


def test_fast_set_is_feet_trunk_and_upper_calves():
    fast = _colliding(robot.build_model(None))
    assert fast == {"trunk", *FOOT_NAMES, "FL_calf", "FR_calf", "RL_calf", "RR_calf"}
    full_model = robot.build_model(None, collision="full")
    full = _colliding(full_model)
    assert full == fast | {"FL_thigh", "FR_thigh", "RL_thigh", "RR_thigh"}
    fast_calf = robot.build_model(None).geom("FL_calf").size[1]
    assert fast_calf == pytest.approx(0.05)
    assert full_model.geom("FL_calf").size[1] == pytest.approx(CALF_COLLISION_FULL / 2)


def test_the_lower_shin_collides_only_in_the_full_set():
    full, fast = _lower_shin_contacts("full"), _lower_shin_contacts("fast")
    assert "FL_calf" in full
    assert "FL_calf" not in fast
    assert "FL_foot" in full and "FL_foot" in fast


def test_unknown_collision_set_is_an_error():
    with pytest.raises(ValueError, match="collision='feet'"):
        robot.build_model(None, collision="feet")
    with pytest.raises(ValueError, match="collision='none'"):
        EnvConfig(collision="none")

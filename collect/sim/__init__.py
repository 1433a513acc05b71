"""Batched MuJoCo simulation of an A1-class quadruped on legged_gym-style terrain."""

import os
import sys

from gymnasium.envs.registration import register, registry

# MuJoCo picks its offscreen GL backend when it is first imported. Headless Linux machines
# render through EGL; elsewhere MuJoCo's own default (GLFW) is right. A user's setting wins.
if sys.platform.startswith("linux") and "mujoco" not in sys.modules:
    os.environ.setdefault("MUJOCO_GL", "egl")

# Gymnasium: importing this package registers "msta/A1-v0" (see gym_env.py), the way
# Gymnasium's plugin packages do. The entry points are strings, so MuJoCo and gym_env load
# only when an env is made.
if "msta/A1-v0" not in registry:
    register(id="msta/A1-v0", entry_point="msta.collect.sim.gym_env:MstaEnv",
             vector_entry_point="msta.collect.sim.gym_env:MstaVectorEnv")

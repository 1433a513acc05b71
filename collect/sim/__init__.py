"""Batched MuJoCo simulation of an A1-class quadruped on legged_gym-style terrain."""

import os
import sys

# MuJoCo picks its offscreen GL backend when it is first imported. Headless Linux machines
# render through EGL; elsewhere MuJoCo's own default (GLFW) is right. A user's setting wins.
if sys.platform.startswith("linux") and "mujoco" not in sys.modules:
    os.environ.setdefault("MUJOCO_GL", "egl")

"""Recording, the one rollout loop and the simulator (msta.collect.sim).

MuJoCo picks its offscreen GL backend when it is first imported, and modules here import
it (the rollout loop films through it). Headless Linux machines render through EGL;
elsewhere MuJoCo's own default (GLFW) is right; a user's MUJOCO_GL wins. This package's
import runs before any of its modules', so the default is in place before MuJoCo loads.
"""

import os
import sys

if sys.platform.startswith("linux") and "mujoco" not in sys.modules:
    os.environ.setdefault("MUJOCO_GL", "egl")

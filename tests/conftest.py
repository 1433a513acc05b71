"""Shared test setup. Headless rendering needs MuJoCo's EGL backend chosen before import."""

import os
import sys

if sys.platform.startswith("linux"):
    os.environ.setdefault("MUJOCO_GL", "egl")

"""Shared test setup. Headless rendering needs MuJoCo's EGL backend chosen before import."""

import os
import sys

if sys.platform.startswith("linux"):
    os.environ.setdefault("MUJOCO_GL", "egl")


def _register_helpers() -> None:
    """Make ``msta_test_helpers.py`` (builders several test packages share) importable as
    ``msta_test_helpers``: with --import-mode=importlib this folder is not on sys.path, and
    this conftest runs before any test module or deeper conftest is imported."""
    import importlib.util
    from pathlib import Path

    name = "msta_test_helpers"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(
            name, Path(__file__).with_name("msta_test_helpers.py"))
        sys.modules[name] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(sys.modules[name])


_register_helpers()

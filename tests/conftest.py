"""Shared test setup. Headless rendering needs MuJoCo's EGL backend chosen before import."""

import os
import sys

if sys.platform.startswith("linux"):
    os.environ.setdefault("MUJOCO_GL", "egl")


#: modules that hold no tests, importable by these names: with --import-mode=importlib no
#: test folder is on sys.path, and this conftest runs before any test module or deeper
#: conftest is imported
HELPERS = {
    "msta_test_helpers": "msta_test_helpers.py",  # builders several test packages share
    "msta_hub_security_helpers": "msta_data/hub_security_helpers.py",  # raw-HTTP hub tests
}


def _register_helpers() -> None:
    import importlib.util
    from pathlib import Path

    for name, path in HELPERS.items():
        if name not in sys.modules:
            spec = importlib.util.spec_from_file_location(name, Path(__file__).parent / path)
            sys.modules[name] = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(sys.modules[name])


_register_helpers()

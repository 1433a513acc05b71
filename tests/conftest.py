"""Shared test setup. Headless rendering needs MuJoCo's EGL backend chosen before import."""

import os
import sys

import pytest

if sys.platform.startswith("linux"):
    os.environ.setdefault("MUJOCO_GL", "egl")


#: modules that hold no tests, importable by these names: with --import-mode=importlib no
#: test folder is on sys.path, and this conftest runs before any test module or deeper
#: conftest is imported
HELPERS = {
    "msta_test_helpers": "msta_test_helpers.py",  # builders several test packages share
    "msta_hub_security_helpers": "msta_data/hub_security_helpers.py",  # raw-HTTP hub tests
    "msta_source_tree": "msta_source_tree.py",  # the source files as modules, their imports
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


@pytest.fixture(scope="module")
def local_ray():
    """A local Ray of 2 CPUs for one test module (Ray imported only where a test asks)."""
    import ray

    from msta.collect import ray_pool

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level="warning")
    yield
    ray_pool.close_shared()
    ray.shutdown()

"""Every ``msta-*`` command answers ``--help`` before the heavy libraries load: parsing needs
only the configs, and torch, pandas, LeRobot and the rest are imported once a run starts
(``# lazy:`` imports after parsing). Checked structurally, in a fresh interpreter per
command: after ``--help`` none of them is in ``sys.modules``."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib

import pytest
from msta_source_tree import REPO

#: What a command may load only after its command line is parsed (each costs 0.2-1.5 s).
HEAVY = ("torch", "pandas", "lerobot", "datasets", "ray", "rsl_rl", "tensordict",
         "matplotlib", "onnxruntime")
SCRIPTS = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]
#: Run in a fresh interpreter: ``<command> --help``, then print what got imported.
PROBE = """
import importlib, json, sys
module, function, prog, heavy = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4:]
sys.argv = [prog, "--help"]
try:
    getattr(importlib.import_module(module), function)()
except SystemExit as e:
    code = e.code
else:
    code = None
print(json.dumps({"code": code, "loaded": sorted(h for h in heavy if h in sys.modules)}))
"""


def help_imports(name: str) -> dict:
    module, function = SCRIPTS[name].split(":")
    out = subprocess.run([sys.executable, "-c", PROBE, module, function, name, *HEAVY],
                         capture_output=True, text=True, check=True, cwd=REPO)
    return {**json.loads(out.stdout.strip().splitlines()[-1]), "help": out.stdout}


@pytest.mark.parametrize("name", sorted(SCRIPTS))
def test_help_loads_no_heavy_library(name):
    got = help_imports(name)
    assert got["code"] in (0, None) and "usage:" in got["help"], got["help"][-500:]
    assert got["loaded"] == [], f"{name} --help imported {got['loaded']}"


def test_the_probe_sees_a_heavy_import(tmp_path, monkeypatch):
    """The probe reports a library a command imports before parsing."""
    (tmp_path / "heavy_cmd.py").write_text(
        "import sys\nimport pandas  # noqa: F401\n\n\ndef main():\n"
        "    print('usage: heavy')\n    raise SystemExit(0)\n")
    out = subprocess.run([sys.executable, "-c", PROBE, "heavy_cmd", "main", "heavy", *HEAVY],
                         capture_output=True, text=True, check=True, cwd=tmp_path)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == {"code": 0, "loaded": ["pandas"]}


def test_the_light_configs_name_every_shipped_student():
    """``--policy.type`` knows each shipped student from its config alone (no torch): the
    configs registered by ``register_builtin_configs`` are all the registered policies."""
    code = (
        "import json, sys\n"
        "from msta.policies.config import PolicyConfig\n"
        "from msta.policies.registry import register_builtin_configs, registered_policies\n"
        "register_builtin_configs()\n"
        "light = sorted(PolicyConfig.get_known_choices()); torch = 'torch' in sys.modules\n"
        "print(json.dumps([light, torch, registered_policies()]))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=REPO)
    light, torch_loaded, registered = json.loads(out.stdout.strip().splitlines()[-1])
    assert not torch_loaded
    assert light == registered and "msta" in light and "gru" in light

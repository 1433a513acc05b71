"""One import name and no circles: installing msta adds ``msta`` (and the two LeRobot plugins)
to a Python, no module of the tree imports another that imports it back (module level,
inside functions and under ``TYPE_CHECKING`` alike), and an import inside a function says
why it is there (``# lazy: <reason>`` on its first line or the line above)."""

from __future__ import annotations

import ast
import re
import shutil
import subprocess
import sys
import tomllib
import zipfile
from importlib import metadata
from pathlib import Path

from msta_source_tree import (
    FOLDERS,
    OLD_TOP_LEVEL,
    PLUGINS,
    REPO,
    circles,
    import_graph,
    imports,
    imports_not_from_home,
    modules,
)

#: the reason a function-local import gives, on its first line or the line above
LAZY = re.compile(r"#\s*lazy:\s*\S")


def test_no_import_circles():
    found = circles(import_graph())
    assert found == [], "import circles:\n" + "\n".join(" <-> ".join(c) for c in found)


def test_the_circle_check_sees_circles_through_functions_and_type_checking(tmp_path):
    """A circle closed by a function-local import, one closed under TYPE_CHECKING and one
    through ``from package import module`` are all found; a one-way chain is not."""
    (tmp_path / "train").mkdir()
    files = {
        "__init__.py": "",
        "a.py": "from msta.train.b import x\n",
        "b.py": "def f():\n    from msta.train.a import y\n",
        "c.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                "    from msta.train.d import Z\n",
        "d.py": "from msta.train import c\n",
        "e.py": "from msta.train.a import y\n",
    }
    for name, text in files.items():
        (tmp_path / "train" / name).write_text(text)
    assert circles(import_graph(tmp_path)) == [["msta.train.a", "msta.train.b"],
                                               ["msta.train.c", "msta.train.d"]]


def lazy_imports_without_reason(root: Path = REPO) -> list[str]:
    bad = []
    for path in modules(root).values():
        lines = path.read_text().splitlines()
        for imp in imports(path):
            said = lines[imp.line - 1] + (lines[imp.line - 2] if imp.line > 1 else "")
            if imp.local and not LAZY.search(said):
                bad.append(f"{path.relative_to(root)}:{imp.line}: {lines[imp.line - 1].strip()}")
    return sorted(set(bad))


def test_every_function_local_import_says_why():
    """Imports sit at the top of a module; one inside a function keeps a heavy import (or
    a command's whole stack) off a path that does not need it, and says so."""
    bad = lazy_imports_without_reason()
    assert bad == [], "function-local imports without '# lazy: <reason>':\n" + "\n".join(bad)


def test_the_reason_check_sees_a_bare_local_import(tmp_path):
    (tmp_path / "eval").mkdir()
    (tmp_path / "eval" / "m.py").write_text(
        "import json\n\n\ndef f():\n    import numpy  # lazy: off the --help path\n"
        "    x = 1\n    import torch\n    # lazy: only for YAML files\n    import yaml\n"
        "    return numpy, torch, json, yaml, x\n")
    assert lazy_imports_without_reason(tmp_path) == ["eval/m.py:7: import torch"]


def test_every_name_is_imported_from_its_home():
    """One home per concept: code and tests import a name from the module that defines it,
    not through another module that happens to import it (package facades excepted)."""
    bad = imports_not_from_home(extra=tuple((REPO / "tests").rglob("*.py")))
    assert bad == [], "imported through another module:\n" + "\n".join(bad)


def test_the_home_check_sees_a_name_taken_through_another_module(tmp_path):
    (tmp_path / "eval").mkdir()
    (tmp_path / "eval" / "home.py").write_text("X = 1\n\n\ndef f():\n    pass\n")
    (tmp_path / "eval" / "hop.py").write_text("from msta.eval.home import X, f\n")
    (tmp_path / "eval" / "user.py").write_text("from msta.eval.hop import X\n"
                                               "from msta.eval.home import f\n")
    assert imports_not_from_home(tmp_path) == ["eval/user.py:1 msta.eval.hop . X"]


def test_nothing_imports_the_old_top_level_names():
    """Every module, test and plugin imports msta.<layer>; the bare folder names
    (train, eval, ...) are not importable from an installed msta."""
    paths = [*modules().values(), *(REPO / "tests").rglob("*.py")]
    assert len(paths) > 250, len(paths)  # every module, test and plugin
    bad = [f"{path.relative_to(REPO)}:{imp.line} {imp.target}"
           for path in paths for imp in imports(path)
           if imp.target.split(".")[0] in OLD_TOP_LEVEL]
    assert bad == []


def test_pyproject_lists_every_package_of_the_folders():
    setuptools = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert setuptools["package-dir"] == FOLDERS
    on_disk = sorted(name for name, path in modules(plugins=False).items()
                     if path.name == "__init__.py")
    assert sorted(setuptools["packages"]) == on_disk


def test_the_installed_distribution_adds_one_import_name():
    """The wheel holds ``msta/`` and its metadata only; the installed (editable) msta names
    one top-level module and maps only ``msta.*`` onto the folders."""
    assert metadata.distribution("msta").read_text("top_level.txt").split() == ["msta"]
    for plugin in PLUGINS:
        assert metadata.distribution(plugin).read_text("top_level.txt").split() == [plugin]
    finders = [f for f in metadata.distribution("msta").files or ()
               if f.name.startswith("__editable__") and f.name.endswith("_finder.py")]
    for finder in finders:  # an editable install (make's .venv): its name -> folder map
        mapping = ast.literal_eval(re.search(r"MAPPING[^=]*= (\{.*?\})\n",
                                             Path(finder.locate()).read_text()).group(1))
        assert sorted(mapping) == sorted(FOLDERS)


def test_the_wheel_holds_only_msta(tmp_path):
    """Built from a copy of the sources (setuptools writes build/ beside them)."""
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(REPO / name, src / name)
    for folder in FOLDERS.values():
        shutil.copytree(REPO / folder, src / folder,
                        ignore=shutil.ignore_patterns("__pycache__", "*.egg-info", "plugins"))
    out = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                          "--no-build-isolation", "-q", "-w", str(tmp_path), str(src)],
                         capture_output=True, text=True, timeout=300, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    (wheel,) = tmp_path.glob("msta-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert {n.split("/")[0] for n in names} == {"msta", wheel.name.split("-py")[0] + ".dist-info"}
    for must in ("msta/data/sensors.py", "msta/train/offline.py", "msta/eval/apps/demo.py",
                 "msta/collect/sim/assets/a1.xml", "msta/data/robots/a1.toml",
                 "msta/policies/teacher/checkpoints/rma_ppo/model.safetensors"):
        assert must in names


def test_a_folder_holding_train_py_and_friends_shadows_nothing(tmp_path):
    """The most common file names of a machine-learning folder, each failing loudly when
    imported, do not break the LeRobot plugins or an msta command run from there."""
    for name in (*OLD_TOP_LEVEL, "msta_data"):
        (tmp_path / f"{name}.py").write_text(f"raise SystemExit('imported the user\\'s {name}.py')\n")
    plugins = ("from lerobot.utils.import_utils import register_third_party_plugins\n"
               "register_third_party_plugins()\n"
               "import lerobot_env_msta, lerobot_policy_msta\n"
               "from lerobot.configs.policies import PreTrainedConfig\n"
               "assert 'msta' in PreTrainedConfig.get_known_choices()\nprint('plugins ok')\n")
    run = [subprocess.run([sys.executable, "-c", plugins], cwd=tmp_path, capture_output=True,
                          text=True, timeout=300, check=False),
           subprocess.run([sys.executable, "-m", "msta.train.offline", "--help"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300, check=False)]
    assert run[0].returncode == 0 and "plugins ok" in run[0].stdout, run[0].stderr[-2000:]
    assert run[1].returncode == 0 and "--dataset" in run[1].stdout, run[1].stderr[-2000:]
    assert "imported the user" not in run[0].stderr + run[1].stderr

"""Imports run one way (README, "What is where"): each layer may import only the layers
listed for it in ``MAY_IMPORT`` (itself and some of those below it), never one above or a
sibling. A layer is a folder: no list of modules says which module sits where.

    msta.data                       the bottom: data format, sensors, robot constants, hub
    msta.collect.sim  msta.policies the simulator; the students and teachers (siblings:
                                    neither imports the other)
    msta.collect                    recording, the one rollout loop, msta-sim
    msta.eval                       the evaluation library (metrics, msta-eval, reports)
    msta.train                      stage 1 and 2 (its round table uses eval's metrics)
    msta.eval.apps                  msta-compare, msta-repro, the demo: run train and eval
    msta.eval.bench                 the benchmarks: may run anything below them

Every import counts: at module level, inside functions and under ``TYPE_CHECKING``.
"""

from __future__ import annotations

import ast
from pathlib import Path

from msta_source_tree import REPO, imports, modules

#: folders that are a layer of their own inside a top-level package (deepest first).
SUBLAYERS = ("msta.collect.sim", "msta.eval.apps", "msta.eval.bench")
_BASE = {"msta.data"}
_BELOW_EVAL = _BASE | {"msta.collect.sim", "msta.policies", "msta.collect", "msta.eval"}
MAY_IMPORT: dict[str, set[str]] = {
    "msta.data": _BASE,
    "msta.collect.sim": _BASE | {"msta.collect.sim"},
    "msta.policies": _BASE | {"msta.policies"},
    "msta.collect": _BASE | {"msta.collect.sim", "msta.policies", "msta.collect"},
    "msta.eval": _BELOW_EVAL,
    "msta.train": _BELOW_EVAL | {"msta.train"},
    "msta.eval.apps": _BELOW_EVAL | {"msta.train", "msta.eval.apps"},
    "msta.eval.bench": _BELOW_EVAL | {"msta.train", "msta.eval.apps", "msta.eval.bench"},
}


#: the LeRobot plugins sit in the layer of the folder they live in
PLUGIN_LAYERS = {"lerobot_env_msta": "msta.collect", "lerobot_policy_msta": "msta.train"}


def layer(module: str) -> str | None:
    if module.split(".")[0] in PLUGIN_LAYERS:
        return PLUGIN_LAYERS[module.split(".")[0]]
    for sub in SUBLAYERS:
        if module == sub or module.startswith(sub + "."):
            return sub
    top = ".".join(module.split(".")[:2])
    return top if top in MAY_IMPORT else None


def forbidden_imports(root: Path = REPO) -> list[str]:
    bad = []
    for module, path in modules(root).items():
        me = layer(module)
        assert me is not None, module
        for imp in imports(path):
            # from msta.eval import apps: the name may be a module of another layer
            node = imp.statement
            name = imp.target if isinstance(node, ast.Import) else (
                imp.target if layer(imp.target) != layer(node.module) else node.module)
            other = layer(name)
            if other is not None and other not in MAY_IMPORT[me]:
                bad.append(f"{path.relative_to(root)}:{imp.line} ({me}) imports "
                           f"{name} ({other})")
    return list(dict.fromkeys(bad))


def test_no_package_imports_a_layer_it_may_not():
    assert forbidden_imports() == []


def test_every_layer_may_import_only_itself_and_layers_below():
    order = list(MAY_IMPORT)
    for i, me in enumerate(order):
        assert me in MAY_IMPORT[me]
        assert MAY_IMPORT[me] <= set(order[:i + 1]), me


def test_the_check_sees_violations(tmp_path):
    """The walk really parses imports: a layer-0 module importing policies, a policy
    importing the simulator (siblings), train importing an eval app, an app importing a
    benchmark (``from msta.eval import bench`` too) and the eval library importing train are
    reported; an app importing train is not."""
    for folder in ("msta_data", "collect", "policies", "train", "eval", "eval/apps"):
        (tmp_path / folder).mkdir()
    (tmp_path / "msta_data" / "bad.py").write_text(
        "def f():\n    from msta.policies.factory import load_policy\n")
    (tmp_path / "policies" / "bad.py").write_text("import msta.collect.sim.env\n")
    (tmp_path / "train" / "bad.py").write_text("from msta.eval.apps.demo import main\n")
    (tmp_path / "eval" / "apps" / "demo.py").write_text("from msta.train.offline import train\n")
    (tmp_path / "eval" / "apps" / "bad.py").write_text(
        "from msta.eval import bench, metrics\nfrom msta.eval.bench.learn import main\n")
    (tmp_path / "eval" / "bad.py").write_text("import msta.train.loop\n")
    assert sorted(forbidden_imports(tmp_path)) == [
        "eval/apps/bad.py:1 (msta.eval.apps) imports msta.eval.bench (msta.eval.bench)",
        "eval/apps/bad.py:2 (msta.eval.apps) imports msta.eval.bench.learn (msta.eval.bench)",
        "eval/bad.py:1 (msta.eval) imports msta.train.loop (msta.train)",
        "msta_data/bad.py:2 (msta.data) imports msta.policies.factory (msta.policies)",
        "policies/bad.py:1 (msta.policies) imports msta.collect.sim.env (msta.collect.sim)",
        "train/bad.py:1 (msta.train) imports msta.eval.apps.demo (msta.eval.apps)",
    ]

"""Imports run one way (README, "What is where"): each layer may import only the layers
listed for it in ``MAY_IMPORT`` (itself and some of those below it), never one above or a
sibling. A layer is a folder: no list of modules says which module sits where.

    msta_data                       the bottom: data format, sensors, robot constants, hub
    collect.sim    policies         the simulator; the students and teachers (siblings:
                                    neither imports the other)
    collect                         recording, the one rollout loop, msta-sim
    eval                            the evaluation library (metrics, msta-eval, reports)
    train                           stage 1 and 2 (its round table uses eval's metrics)
    eval.apps                       msta-compare, msta-repro, the demo: run train and eval
    eval.bench                      the benchmarks: may run anything below them
"""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: folders that are a layer of their own inside a top-level package (deepest first).
SUBLAYERS = ("collect.sim", "eval.apps", "eval.bench")
_BASE = {"msta_data"}
MAY_IMPORT: dict[str, set[str]] = {
    "msta_data": _BASE,
    "collect.sim": _BASE | {"collect.sim"},
    "policies": _BASE | {"policies"},
    "collect": _BASE | {"collect.sim", "policies", "collect"},
    "eval": _BASE | {"collect.sim", "policies", "collect", "eval"},
    "train": _BASE | {"collect.sim", "policies", "collect", "eval", "train"},
    "eval.apps": _BASE | {"collect.sim", "policies", "collect", "eval", "train", "eval.apps"},
    "eval.bench": _BASE | {"collect.sim", "policies", "collect", "eval", "train", "eval.apps",
                           "eval.bench"},
}


def layer(module: str) -> str | None:
    for sub in SUBLAYERS:
        if module == sub or module.startswith(sub + "."):
            return sub
    top = module.split(".")[0]
    return top if top in MAY_IMPORT else None


def forbidden_imports(root: Path = REPO) -> list[str]:
    bad = []
    for top in ("msta_data", "collect", "policies", "train", "eval"):
        for path in sorted((root / top).rglob("*.py")):
            module = ".".join(path.relative_to(root).with_suffix("").parts)
            me = layer(module)
            assert me is not None, module
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                    # from eval import apps: a name may be a module of another layer
                    names = list(dict.fromkeys(
                        f"{node.module}.{a.name}"
                        if layer(f"{node.module}.{a.name}") != layer(node.module) else node.module
                        for a in node.names))
                else:
                    continue
                for name in names:
                    other = layer(name)
                    if other is not None and other not in MAY_IMPORT[me]:
                        bad.append(f"{path.relative_to(root)}:{node.lineno} ({me}) imports "
                                   f"{name} ({other})")
    return bad


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
    benchmark (``from eval import bench`` too) and the eval library importing train are
    reported; an app importing train is not."""
    for folder in ("msta_data", "collect", "policies", "train", "eval", "eval/apps"):
        (tmp_path / folder).mkdir()
    (tmp_path / "msta_data" / "bad.py").write_text(
        "def f():\n    from policies.factory import load_policy\n")
    (tmp_path / "policies" / "bad.py").write_text("import collect.sim.env\n")
    (tmp_path / "train" / "bad.py").write_text("from eval.apps.demo import main\n")
    (tmp_path / "eval" / "apps" / "demo.py").write_text("from train.offline import train\n")
    (tmp_path / "eval" / "apps" / "bad.py").write_text(
        "from eval import bench, metrics\nfrom eval.bench.learn import main\n")
    (tmp_path / "eval" / "bad.py").write_text("import train.loop\n")
    assert forbidden_imports(tmp_path) == [
        "msta_data/bad.py:2 (msta_data) imports policies.factory (policies)",
        "policies/bad.py:1 (policies) imports collect.sim.env (collect.sim)",
        "train/bad.py:1 (train) imports eval.apps.demo (eval.apps)",
        "eval/apps/bad.py:1 (eval.apps) imports eval.bench (eval.bench)",
        "eval/apps/bad.py:2 (eval.apps) imports eval.bench.learn (eval.bench)",
        "eval/bad.py:1 (eval) imports train.loop (train)",
    ]

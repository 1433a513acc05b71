"""Imports run one way (README, "What is where"): a module may import its own layer and
the layers below it, never one above.

    msta_data  <-  collect.sim  <-  policies  <-  collect (record, rollout, simulate)
               <-  train / eval

train and eval form one top layer for now: stage 2's round table uses msta-eval's
Evaluator (one metric path) while msta-compare runs stage 1 and 2 (issue 16 asks to split
them; until then this test keeps every layer below them clean).
"""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RANK = {"msta_data": 0, "collect.sim": 1, "policies": 2, "collect": 3, "train": 4, "eval": 4}


def layer(module: str) -> str | None:
    if module == "collect.sim" or module.startswith("collect.sim."):
        return "collect.sim"
    top = module.split(".")[0]
    return top if top in RANK else None


def imports_above(root: Path = REPO) -> list[str]:
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
                    names = [node.module]
                else:
                    continue
                for name in names:
                    other = layer(name)
                    if other is not None and RANK[other] > RANK[me]:
                        bad.append(f"{path.relative_to(root)}:{node.lineno} ({me}) imports "
                                   f"{name} ({other})")
    return bad


def test_no_package_imports_a_layer_above_it():
    assert imports_above() == []


def test_the_check_sees_a_violation(tmp_path):
    """The walk really parses imports: a layer-0 module importing policies is reported."""
    fake = tmp_path / "msta_data"
    fake.mkdir()
    (fake / "bad.py").write_text("def f():\n    from policies.factory import load_policy\n")
    for top in ("collect", "policies", "train", "eval"):
        (tmp_path / top).mkdir()
    assert imports_above(tmp_path) == ["msta_data/bad.py:2 (msta_data) imports policies.factory "
                               "(policies)"]

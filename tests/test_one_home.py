"""One home per default: the default teacher, the paper's mask ratios and the stage-2
rollout masks are written once, and every command that uses them refers to that place."""

from __future__ import annotations

import ast
from pathlib import Path

from msta_source_tree import REPO, modules

from msta.eval.apps.compare import CompareConfig
from msta.eval.apps.demo import DemoConfig
from msta.eval.apps.repro import ReproConfig
from msta.policies.msta import MSTAConfig
from msta.policies.teacher.config import TeacherConfig
from msta.train.config import STAGE2_MASK_RATIO, STAGE2_ROLLOUT_MASK_RATIOS, training_mask_ratio

#: the one module that names the shipped teachers' folders
TEACHER_HOME = REPO / "policies" / "teacher" / "config.py"


def literal_mask_defaults(paths: list[Path], root: Path = REPO) -> list[str]:
    """``file:line field = value``: a config field or argument named ``*mask_ratio*`` whose
    default is a non-zero number written out instead of a name."""
    bad = []
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            pairs = []
            if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
                pairs = [(node.target.id, node.value)]
            elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                args = node.args.args[len(node.args.args) - len(node.args.defaults):]
                pairs = list(zip([a.arg for a in args], node.args.defaults, strict=True))
            for name, value in pairs:
                if ("mask_ratio" in name or name == "mask") and isinstance(value, ast.Constant) \
                        and isinstance(value.value, float) and value.value != 0.0:
                    bad.append(f"{path.relative_to(root)}:{value.lineno} {name} = {value.value}")
    return sorted(bad)


def test_no_command_writes_a_mask_ratio_out_again():
    """The policy configs own their stage-1 ratios (MSTA's 0.75); train.config the stage-2
    ones; the commands, loops and apps refer to them."""
    home = REPO / "train" / "config.py"
    paths = [p for name, p in modules(plugins=False).items() if p != home
             and name.startswith(("msta.train", "msta.eval", "msta.collect"))]
    assert literal_mask_defaults(paths) == []


def test_the_mask_check_sees_a_literal(tmp_path):
    src = tmp_path / "m.py"
    src.write_text("class C:\n    train_mask_ratio: float = 0.75\n    other: float = 0.5\n\n\n"
                   "def f(mask: float = 0.5, mask_ratio: float = 0.0):\n    pass\n")
    assert literal_mask_defaults([src], tmp_path) == ["m.py:2 train_mask_ratio = 0.75",
                                                      "m.py:6 mask = 0.5"]


def test_the_shipped_teacher_is_named_in_one_module():
    """``TeacherConfig()`` is the default teacher (rma_ppo); no command spells it out."""
    others = [p.relative_to(REPO) for p in modules().values()
              if p != TEACHER_HOME and "SHIPPED_RMA" in p.read_text()]
    assert others == []
    assert DemoConfig().teacher == ReproConfig().teacher == TeacherConfig()


def test_the_commands_defaults_are_the_one_rules():
    demo = DemoConfig()
    assert demo.train_mask_ratio == MSTAConfig().mask_ratio == training_mask_ratio(None, 0.75)
    assert demo.correct_mask_ratio == CompareConfig.stage2_mask_ratio == STAGE2_MASK_RATIO
    assert demo.rollout_mask_ratios == STAGE2_ROLLOUT_MASK_RATIOS == (0.0, STAGE2_MASK_RATIO)

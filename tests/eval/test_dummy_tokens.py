"""msta-eval's dummy_tokens scenario end to end: MSTA rows at 0 and 256 dummy tokens, the
teacher and a GRU baseline not applicable at 256."""

from __future__ import annotations

import json

import torch

from msta.data.stats import load_stats
from msta.eval.evaluate import main
from msta.eval.scenarios import SUITES, build_conditions
from msta.policies.baselines.configs import GRUConfig
from msta.policies.factory import make_policy


def test_suites_sweep_dummy_tokens() -> None:
    assert SUITES["quick"].values["dummy_tokens"] == (0, 256)
    assert SUITES["paper"].values["dummy_tokens"] == (0, 64, 256)
    conds = build_conditions(["dummy_tokens"], SUITES["quick"], ("joint_pos",), seed=3)
    assert [(c.label, c.spec.dummy_tokens, c.spec.seed) for c in conds] == [
        ("dummy 0", 0, 3), ("dummy 256", 256, 3)]


def test_cli_dummy_tokens_msta_ok_gru_not_applicable(tiny_ckpt, tmp_path, capsys) -> None:
    torch.manual_seed(0)
    gru = make_policy(GRUConfig.from_preset("tiny"), load_stats(tiny_ckpt.parent / "dataset"))
    gru_dir = gru.save_pretrained(tmp_path / "gru_tiny")
    out = tmp_path / "eval"
    main(["--policies", f"teacher,{tiny_ckpt},{gru_dir}", "--suite", "quick",
          "--scenarios", "dummy_tokens", "--terrains", "flat", "--levels", "0", "--trials", "2",
          "--episode_length_s", "0.3", "--progress", "false", "--output_dir", str(out)])
    metrics = json.loads((out / "metrics.json").read_text())
    runs = {(r["policy"], r["condition"]): r for r in metrics["runs"]}
    msta, base = runs[("msta_tiny", "dummy 256")], runs[("msta_tiny", "dummy 0")]
    assert msta["status"] == base["status"] == "ok"
    assert msta["spec"]["dummy_tokens"] == 256 and "dummy_tokens" not in base["spec"]
    assert msta["inputs"] != base["inputs"] and msta["raw"] != base["raw"]
    assert runs[("gru_tiny", "dummy 0")]["status"] == "ok"
    assert runs[("gru_tiny", "dummy 256")]["status"] == "n/a"
    assert "no token input" in runs[("gru_tiny", "dummy 256")]["reason"]
    assert runs[("teacher", "dummy 256")]["status"] == "n/a"
    report = (out / "report.md").read_text()
    assert "## Random dummy tokens appended at test time" in report
    assert "| gru_tiny | dummy_tokens/dummy 256 | NotImplementedError: GRUPolicy has no token" \
        in report
    assert (out / "dummy_tokens.png").stat().st_size > 1000

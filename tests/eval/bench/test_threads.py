"""make bench-threads at a tiny size: the default and every fixed count run as real
msta-train commands beside a busy process, and the last line states the default's ratio."""

from __future__ import annotations

import json

from msta.data.threads import usable_cores
from msta.eval.bench import threads as bench


def test_the_benchmark_measures_the_default_against_every_count(tmp_path, capsys):
    out = tmp_path / "bench"
    bench.main([f"--output_dir={out}", "--steps=8", "--rounds=1", "--episodes=2",
                "--frames=40", "--batch_size=8", "--states=[loaded]", "--load=1"])
    res = json.loads((out / "results.json").read_text())
    rates = res["samples_per_s"]["loaded"]
    assert sorted(rates) == sorted(name for name, _ in bench.settings())
    assert len(rates) == usable_cores() + 1 and all(v > 0 for v in rates.values())
    ratio = res["default_vs_best"]["loaded"]
    assert ratio == rates["default"] / max(v for k, v in rates.items() if k != "default")
    assert capsys.readouterr().out.rstrip().endswith(f"default vs best: loaded {ratio:.2f}")

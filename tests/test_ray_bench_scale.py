"""make bench-scale at a tiny size on a real local Ray: every stage measured in every
configuration, the ratios against the single process, and the closing line."""

from __future__ import annotations

import json
import re

from msta.eval.bench.scale import main


def test_bench_scale_measures_every_stage_against_the_single_process(local_ray, tmp_path,
                                                                     capsys):
    main(["--workers=1", "--rounds=1", "--episodes=2", "--num_envs=1", "--episode_length_s=0.1",
          "--stage2_episodes=1", "--trials=2", "--committer_s=0.2", f"--output_dir={tmp_path}"])
    lines = capsys.readouterr().out.strip().splitlines()
    assert re.fullmatch(r"ray-1 / single process: collect [\d.]+, stage 2 [\d.]+, eval [\d.]+",
                        lines[-1])
    res = json.loads((tmp_path / "results.json").read_text())
    assert set(res["stages"]) == {"collect", "stage2", "eval"}
    for stage, row in res["stages"].items():
        names = {"single", "ray-1"} | ({"single-1-thread"} if stage != "eval" else set())
        assert set(row) == names
        assert row["single"]["ratio"] == 1.0
        assert all(r["per_s"] > 0 and r["ratio"] > 0 for r in row.values())
    assert res["committer_frames_per_s"] > 0 and len(res["load_average_1min"]) == 2

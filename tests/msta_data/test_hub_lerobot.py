"""A dataset pushed with msta.data.hub_push loads with LeRobotDataset(repo_id, revision="v3.0").

lerobot's hub client reads HF_ENDPOINT when huggingface_hub is imported, so the LeRobot side
runs in a fresh process started with HF_ENDPOINT pointing at the test server.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from msta.data.hub_server import HubServer, ServerConfig

SECRET = "alice-secret-0001"

SCRIPT = textwrap.dedent("""
    import sys
    from pathlib import Path
    import numpy as np
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from msta.data.hub_push import push_dataset

    tmp = Path(sys.argv[1])
    features = {"observation.state": {"dtype": "float32", "shape": (3,), "names": ["a", "b", "c"]},
                "action": {"dtype": "float32", "shape": (2,), "names": ["x", "y"]}}
    ds = LeRobotDataset.create("alice/tiny", fps=50, features=features, root=tmp / "src", use_videos=False,
                               robot_type="unitree_a1")
    for i in range(4):
        ds.add_frame({"observation.state": np.full(3, i, np.float32), "action": np.full(2, -i, np.float32),
                      "task": "walk"})
    ds.save_episode()
    ds.finalize()
    sha = push_dataset(tmp / "src", "alice/tiny")
    loaded = LeRobotDataset("alice/tiny", root=tmp / "downloaded", revision="v3.0")
    print("RESULT", sha, len(loaded), loaded[2]["observation.state"].tolist(), loaded[3]["action"].tolist())
""")


@pytest.mark.slow
def test_lerobot_loads_pushed_dataset_by_codebase_tag(tmp_path):
    with HubServer(ServerConfig(root=tmp_path / "hub", tokens=[f"alice:{SECRET}"])) as srv:
        env = {**os.environ, "HF_ENDPOINT": srv.url, "HF_TOKEN": SECRET, "HF_HOME": str(tmp_path / "hf"),
               "HF_LEROBOT_HOME": str(tmp_path / "lerobot")}
        out = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path)], check=False, env=env, capture_output=True,
                             text=True, timeout=300)
        assert out.returncode == 0, out.stderr[-3000:]
        result = next(line for line in out.stdout.splitlines() if line.startswith("RESULT")).split(" ", 2)
        refs = srv.app.storage.refs(srv.app.storage.get_repo("dataset", "alice/tiny"))
    assert refs["tags"]["v3.0"] == result[1]
    assert result[2] == "4 [2.0, 2.0, 2.0] [-3.0, -3.0]"
    assert (tmp_path / "downloaded" / "meta" / "info.json").is_file()

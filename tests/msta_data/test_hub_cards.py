"""Cards as users meet them: the dataset card the writer keeps true on every append (msta-correct's
own append included) and push-dataset rebuilds, the model card's usage snippet run as written,
and ``msta-hub versions`` in a 100-column terminal; all against the real hub server on 127.0.0.1."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pandas as pd
import pytest
import torch

from msta.data import features as F
from msta.data.cli import parse_config
from msta.data.hub_cards import CardInfo, card_metadata
from msta.data.hub_cli import main as cli_main
from msta.data.hub_ids import hub_api
from msta.data.hub_pull import pull
from msta.data.hub_push import push, push_dataset
from msta.data.hub_server import HubServer, ServerConfig
from msta.data.hub_versions import RepoVersions, Version
from msta.eval.eval_config import EvalConfig
from msta.train.cli import parse_cli
from msta.train.train_config import TrainConfig

SECRET = "alice-secret-0001"


@pytest.fixture
def server(tmp_path, monkeypatch):
    srv = HubServer(ServerConfig(root=tmp_path / "hub", tokens=[f"alice:{SECRET}"])).start()
    monkeypatch.setenv("HF_ENDPOINT", srv.url)
    monkeypatch.setenv("HF_TOKEN", SECRET)
    monkeypatch.setenv("MSTA_HUB_CACHE", str(tmp_path / "cache"))
    yield srv
    srv.stop()


def read_card(root: Path) -> tuple[dict, str]:
    text = (root / "README.md").read_text()
    return card_metadata(text), text


def episode_counts(root: Path) -> dict[str, dict[str, dict[str, int]]]:
    """Episodes and frames by source / round / terrain, read with pandas from the Parquet
    files themselves (frames from the data files, provenance from the episode files)."""
    eps = pd.concat(pd.read_parquet(p) for p in sorted((root / "meta/episodes").rglob("*.parquet")))
    data = pd.concat(pd.read_parquet(p, columns=["episode_index"])
                     for p in sorted((root / "data").rglob("*.parquet")))
    eps = eps.set_index("episode_index")
    eps["frames"] = data.groupby("episode_index").size()
    out = {}
    for key, col in (("by_source", "source"), ("by_round", "round"), ("by_terrain", "terrain")):
        groups = eps.groupby(eps[f"provenance/{col}"].astype(str))
        out[key] = {str(k): {"episodes": int(len(g)), "frames": int(g["frames"].sum())}
                    for k, g in groups}
    return out


def student_episodes(synth, n: int, round_: int, seed0: int) -> list:
    return [(synth.episode(3 + i, seed0 + i), synth.provenance(seed0 + i, "student", round_))
            for i in range(n)]


# ----- dataset cards ---------------------------------------------------------------------
def test_the_writer_keeps_the_dataset_card_true_on_every_append(tmp_path, write_dataset, synth):
    from lerobot.datasets.utils import create_lerobot_dataset_card

    from msta.train.stage2 import append_episodes

    root = tmp_path / "ds"
    write_dataset(root, [4, 5, 6, 7, 3], flush_every_frames=9)  # several commits
    meta, text = read_card(root)
    info = json.loads((root / "meta/info.json").read_text())
    assert meta["msta"]["lerobot"]["total_episodes"] == info["total_episodes"] == 5
    assert meta["msta"]["provenance"] == episode_counts(root)
    assert set(meta["msta"]["provenance"]["by_source"]) == {"teacher"}

    # LeRobot's front matter, plus robot_type and fps
    lerobot = create_lerobot_dataset_card(dataset_info=None, license="apache-2.0").data.to_dict()
    for key in ("license", "task_categories", "configs"):
        assert meta[key] == lerobot[key], key
    assert meta["tags"][: len(lerobot["tags"])] == lerobot["tags"]
    assert (meta["robot_type"], meta["fps"]) == (info["robot_type"], info["fps"]) == ("a1", 50)

    # every feature: name, dtype, shape, and its channel names or a description
    rows = {m.group(1): m.group(2) for m in re.finditer(r"^\| `([^`]+)` \| (.*) \|$", text, re.MULTILINE)}
    assert list(rows) == list(info["features"])
    for col, ft in info["features"].items():
        dtype, shape, desc = rows[col].split(" | ", 2)
        assert dtype == ft["dtype"] and shape == f"({ft['shape'][0]},)", col
        names = ft["names"] or []
        assert desc and (len(names) > 12 or all(n in desc for n in names)), col
    assert "187 channels" in rows["privileged.height_scan"]

    # stage 2 appends the student's episodes: the card says the new counts at once
    assert append_episodes(root, student_episodes(synth, 3, 1, 40)) == 8
    assert append_episodes(root, student_episodes(synth, 2, 2, 50)) == 10
    meta, text = read_card(root)
    info = json.loads((root / "meta/info.json").read_text())
    lerobot_sizes = meta["msta"]["lerobot"]
    assert (lerobot_sizes["total_episodes"], lerobot_sizes["total_frames"]) == \
        (info["total_episodes"], info["total_frames"]) == (10, 25 + 12 + 7)
    counts = episode_counts(root)
    assert meta["msta"]["provenance"] == counts
    assert counts["by_source"] == {"teacher": {"episodes": 5, "frames": 25},
                                   "student": {"episodes": 5, "frames": 19}}
    assert list(counts["by_round"]) == ["0", "1", "2"]
    assert "- **Episodes**: 10, **frames**: 44" in text
    assert "| student | 5 | 19 |" in text and "| 2 | 2 | 7 |" in text
    assert str(tmp_path) not in text


def test_a_readme_of_the_users_own_survives_appends(tmp_path, write_dataset):
    root = tmp_path / "ds"
    write_dataset(root, [3])
    (root / "README.md").write_text("# my notes\n")
    write_dataset(root, [4], seed0=3, append=True)
    assert (root / "README.md").read_text() == "# my notes\n"
    assert not list((root / "meta").glob("*.tmp"))


def test_pushed_dataset_cards_say_the_true_counts(server, tmp_path, write_dataset, synth, capsys):
    """Pushed, pulled, appended to by stage 2 and pushed again: every pushed card counts what
    that commit holds; `msta-hub versions --dataset` lists the sizes of each commit."""
    from msta.train.stage2 import append_episodes

    root = tmp_path / "ds"
    write_dataset(root, [5, 5, 5, 5])
    push_dataset(root, "alice/grow", card=CardInfo(config={"episodes": 4}))
    copy = pull("datasets/alice/grow", tmp_path / "copy")
    append_episodes(copy, student_episodes(synth, 2, 1, 10))
    assert read_card(copy)[0]["msta"]["lerobot"]["total_episodes"] == 6  # before any push
    (copy / "README.md").unlink()  # lost locally: push builds it again from the files
    push_dataset(copy, "alice/grow", card=CardInfo(config={"episodes": 4}))
    meta, text = read_card(pull("datasets/alice/grow", tmp_path / "again"))
    assert meta["msta"]["lerobot"]["total_episodes"] == 6
    assert meta["msta"]["provenance"] == episode_counts(copy)
    assert meta["msta"]["provenance"]["by_round"]["1"] == {"episodes": 2, "frames": 7}
    assert meta["msta"]["config"] == {"episodes": 4}
    assert 'LeRobotDataset("alice/grow", revision="v3.0")' in text
    train = re.search(r"^msta-train .*$", text, re.MULTILINE).group(0).split()
    assert parse_cli(TrainConfig, train[1:], "msta-train").dataset == "datasets/alice/grow@v3.0"

    assert cli_main(["versions", "datasets/alice/grow"]) == 0
    out = capsys.readouterr().out
    assert max(map(len, out.splitlines())) <= 100
    assert "episodes=6 frames=27" in out and "episodes=4 frames=20" in out


# ----- model cards -----------------------------------------------------------------------
def test_the_model_cards_usage_runs_as_written(server, tmp_path, write_dataset):
    """The card's snippet loads the pushed checkpoint (both lines), its convert command makes
    the LeRobot checkpoint its lerobot-eval line names; the card names the dataset revision,
    stage and round, the eval table's trial count and the license, and no local path."""
    from lerobot_policy_msta.convert import PREPROCESSOR_FILE
    from lerobot_policy_msta.convert import main as convert_main
    from msta.data.stats import load_stats
    from msta.policies.factory import make_policy
    from msta.policies.msta import MSTAConfig

    data = tmp_path / "ds"
    write_dataset(data, [6, 6])
    ds_sha = push_dataset(data, "alice/ds")
    cfg = MSTAConfig.from_preset("tiny", input_sensors=("command", "joint_pos", "gravity"))
    policy = make_policy(cfg, load_stats(data))
    ckpt = policy.save_pretrained(tmp_path / "run" / "round_1")
    table = {t: {"lin_tracking_vs_teacher@mask0": 0.9, "survival@mask0": 1.0, "trials": 4.0}
             for t in ("flat", "stairs_up", "average")}
    card = CardInfo(dataset_repo="alice/ds", dataset_revision=ds_sha, stage=2, round=1,
                    config={"dataset": str(data), "output_dir": str(tmp_path / "run"),
                            "policy": {"path": str(tmp_path / "stage1")}},
                    metrics={"eval_trials": 4.0}, eval_table=table)
    push(ckpt, "alice/m", tag="stage2-r1", card=card)
    text = Path(hub_api().hf_hub_download("alice/m", "README.md", revision="stage2-r1")).read_text()
    meta = card_metadata(text)

    assert meta["license"] == "apache-2.0" and "## License" in text
    assert str(tmp_path) not in text and "output_dir" not in meta["msta"]["config"]
    assert meta["msta"]["dataset"] == {"repo": "alice/ds", "revision": ds_sha}
    assert f"dataset `alice/ds` at revision `{ds_sha}`" in text
    assert "- **Stage**: 2, round 1 (online correction" in text
    assert "4 trials (episodes) per row." in text and "| stairs_up | 0.9 | 1 | 4 |" in text

    code = re.search(r"```python\n(.*?)```", text, re.DOTALL).group(1)
    loads = [line for line in code.splitlines() if line.startswith("policy = ")]
    assert len(loads) == 2
    scope: dict = {}
    exec(code.split("\n\n")[0], scope)  # noqa: S102 (the card's own import line)
    for line in loads:
        exec(line, scope)  # noqa: S102 (the card's line, as written)
        got = scope["policy"].state_dict()
        assert got.keys() == policy.state_dict().keys()
        assert all(torch.equal(got[k], v) for k, v in policy.state_dict().items())
    shell = re.search(r"```bash\n(.*?)```", text, re.DOTALL).group(1).splitlines()
    assert shell[0] == "msta-eval --policies teacher,alice/m@stage2-r1 --suite quick"
    assert parse_config(EvalConfig, shell[0].split()[1:], "msta-eval").suite == "quick"
    convert = shell[1].split()
    assert convert[:3] == ["python", "-m", "lerobot_policy_msta.convert"]
    out_dir = tmp_path / "msta_lerobot"
    convert_main([a.replace("=msta_lerobot", f"={out_dir}") for a in convert[3:]])
    assert (out_dir / PREPROCESSOR_FILE).is_file()
    assert shell[2].startswith("lerobot-eval --env.type=msta_a1 --policy.path=msta_lerobot ")


# ----- msta-hub versions -----------------------------------------------------------------
def test_versions_fit_a_100_column_terminal(server, tmp_path, capsys):
    """A stage-2 card's figures, a long commit message, many tags and a metric name longer
    than a line: every line of `msta-hub versions` stays within 100 characters."""
    ckpt = tmp_path / "ckpt"
    ckpt.mkdir()
    (ckpt / "config.json").write_text('{"type": "gru"}')
    names = [f"{f}{ci}@mask{m}" for f in ("lin_tracking_vs_teacher", "total_vs_teacher", "survival")
             for ci in ("", "_ci95_low", "_ci95_high") for m in ("0", "0.25", "0.5", "0.75")]
    table = {t: {n: 0.5 for n in names[:8]} | {"trials": 20.0}
             for t in ("smooth_slope", "rough_slope", "stairs_up", "stairs_down", "average")}
    long_name = "average/" + "very_long_metric_name_" * 6
    card = CardInfo(stage=2, round=3, metrics={n: 0.123456 for n in names} | {long_name: 1.0},
                    eval_table=table)
    sha = push(ckpt, "alice/wide", tag="stage2-r3", card=card,
               message="stage2-r3: " + "a message that goes on and on " * 8)
    for i in range(12):
        hub_api().create_tag("alice/wide", tag=f"experiment-{i:02d}-kept", revision=sha)
    assert cli_main(["versions", "alice/wide"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert max(map(len, lines)) <= 100, max(lines, key=len)
    assert lines[0] == "model alice/wide" and lines[1].startswith(sha[:12])
    text = "\n".join(lines)
    for ref in ("branch main", "tag stage2-r3", "tag experiment-11-kept"):
        assert ref in text
    assert re.search(r"\.\.\. \d+ more metrics \(--json lists them all\)", text)


def test_versions_text_cuts_only_what_does_not_fit():
    metrics = {"x" * 150: 0.5, "total": 0.9}
    tags = [f"t{i}" for i in range(40)]
    c = Version("c" * 40, "push", "2026-01-01T00:00:00+00:00", [], tags, ["main"], metrics)
    lines = RepoVersions("alice/" + "n" * 120, "model", {}, {}, [c]).to_text().splitlines()
    assert max(map(len, lines)) <= 100
    assert lines[1] == "c" * 12 + "  2026-01-01T00:00:00  push"
    assert "tag t39" in "\n".join(lines)
    assert any(line.endswith("xxx=0.5") and line.strip().startswith("...") for line in lines)
    assert lines[-1].strip().endswith("total=0.9")
    one = Version("d" * 40, "push", "2026-01-01T00:00:00+00:00", [], ["v" * 120], [], {})
    lines = RepoVersions("alice/m", "model", {}, {}, [one]).to_text().splitlines()
    assert max(map(len, lines)) <= 100 and lines[2].startswith("    [tag vvv")


def test_features_table_covers_a_schema_1_dataset():
    """A dataset written before the derived columns has its own feature set: every row."""
    from msta.data.hub_cards import features_table

    feats = F.build_features(("joint_pos", "command"), derived=False)
    table = features_table(feats)
    assert [line.split("`")[1] for line in table.splitlines()[2:]] == list(feats)
    assert "observation.state" not in table
    other = features_table({"observation.images.top": {"dtype": "video", "shape": [96, 96, 3],
                                                       "names": ["height", "width", "channel"]},
                            "observation.qpos": {"dtype": "float32", "shape": [2],
                                                 "names": {"motors": ["m0", "m1"]}}})
    assert "| `observation.images.top` | video | (96, 96, 3) | `height, width, channel` |" in other
    assert "| `observation.qpos` | float32 | (2,) | `m0, m1` |" in other


def test_card_tables_print_counts_whole_and_figures_short():
    from msta.data.hub_cards import _markdown_table

    text = _markdown_table({"teacher": {"episodes": 96, "frames": 46653, "loss": 0.0840239}})
    assert text.splitlines()[-1] == "| teacher | 96 | 46653 | 0.08402 |"

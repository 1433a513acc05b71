"""--push_to: msta-train and msta-correct push tagged checkpoints with model cards to a real
hub server (msta.data.hub_server on 127.0.0.1) through the real huggingface_hub client."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from huggingface_hub.errors import HfHubHTTPError

from msta.collect.sim.env_config import EnvConfig
from msta.collect.sim.randomization import RandomizationConfig
from msta.collect.sim.terrain import TerrainConfig
from msta.data.hub_cards import card_metadata
from msta.data.hub_ids import hub_api
from msta.data.hub_pull import pull
from msta.data.hub_push import push_dataset
from msta.data.hub_server import HubServer, ServerConfig
from msta.data.hub_versions import versions
from msta.policies.checkpoint import PolicyPath
from msta.policies.msta import MSTAPolicy
from msta.policies.teacher.config import TeacherConfig
from msta.train.cli import parse_cli
from msta.train.correct_config import PROGRESS, CorrectConfig, RoundEvalConfig
from msta.train.offline import main
from msta.train.push import PushError, dataset_source
from msta.train.stage1 import train
from msta.train.stage2 import correct
from msta.train.train_config import TrainConfig

ALICE, BOB = "alice-secret-0001", "bob-secret-0002"
FAST = ["--policy.preset=tiny", "--policy.input_sensors=[command,joint_pos,gravity]",
        "--policy.history=5", "--batch_size=16", "--warmup_steps=2", "--progress=false",
        "--device=cpu", "--steps=4", "--eval_every=2", "--log_every=2"]
TERRAIN = TerrainConfig(types=("flat", "stairs_up"), num_levels=2, max_init_level=1, border=2.0)


@pytest.fixture
def server(tmp_path, monkeypatch):
    srv = HubServer(ServerConfig(root=tmp_path / "hub", tokens=[f"alice:{ALICE}", f"bob:{BOB}"])).start()
    monkeypatch.setenv("HF_ENDPOINT", srv.url)
    monkeypatch.setenv("HF_TOKEN", ALICE)
    monkeypatch.setenv("MSTA_HUB_CACHE", str(tmp_path / "cache"))
    yield srv
    srv.stop()


def small_env(**kw) -> EnvConfig:
    return EnvConfig(nthread=1, terrain=TERRAIN, randomization=RandomizationConfig(pool_size=2), **kw)


def card_at(repo: str, revision: str) -> dict:
    path = hub_api().hf_hub_download(repo, "README.md", revision=revision)
    return card_metadata(Path(path).read_text())


def correct_cfg(tmp_path: Path, **kw) -> CorrectConfig:
    return CorrectConfig(
        policy=PolicyPath("alice/msta@stage1"), dataset="datasets/alice/ds@v3.0",
        output_dir=str(tmp_path / "stage2"), rounds=1, episodes_per_round=2, num_envs=2,
        episode_length_s=0.3, env=small_env(), teacher=TeacherConfig(type="gait"), steps=3,
        batch_size=8, warmup_steps=1, progress=False, device="cpu", push_to="alice/msta",
        eval=RoundEvalConfig(trials=2, episode_length_s=0.3, terrains="flat,stairs_up", levels="0",
                        mask_ratios=(0.0, 0.5)),
        **kw)


def test_train_and_correct_push_tagged_checkpoints_with_cards(synthetic_dataset, server, tmp_path,
                                                               monkeypatch, capsys):
    ds_sha = push_dataset(synthetic_dataset, "alice/ds")

    # stage 1: the dataset comes from the hub; final/ is pushed with tag stage1
    main(["--dataset=datasets/alice/ds@v3.0", f"--output_dir={tmp_path / 'stage1'}", *FAST,
          "--push_to=alice/msta"])
    meta = card_at("alice/msta", "stage1")
    msta = meta["msta"]
    assert msta["stage"] == 1 and "round" not in msta
    assert msta["dataset"] == {"repo": "alice/ds", "revision": ds_sha}
    assert meta["datasets"] == ["alice/ds"]
    assert msta["config"]["dataset"] == "datasets/alice/ds@v3.0" and msta["config"]["steps"] == 4
    assert msta["config"]["policy"]["history"] == 5
    assert msta["metrics"]["step"] == 4 and msta["metrics"]["train_loss"] > 0
    assert msta["metrics"]["val_loss"] > 0
    pulled = pull("alice/msta@stage1", tmp_path / "pulled1")
    assert MSTAPolicy.from_pretrained(pulled).config.history == 5

    # stage 2 from the hub checkpoint; bob's token may not write to alice/: the push fails
    # after the round is saved and evaluated, and --resume=true pushes it without redoing it
    monkeypatch.setenv("HF_TOKEN", BOB)
    with pytest.raises(PushError, match=r"(?s)saved at .*round_1.*alice/msta@stage2-r1.*--resume=true"):
        correct(correct_cfg(tmp_path))
    out = tmp_path / "stage2"
    prog = json.loads((out / PROGRESS).read_text())
    assert prog["rounds"]["1"]["evaluated"] and "pushed" not in prog["rounds"]["1"]
    assert (out / "round_1" / "model.safetensors").is_file()
    monkeypatch.setenv("HF_TOKEN", ALICE)
    prog = correct(correct_cfg(tmp_path, resume=True))
    rec = prog.rounds[1]
    assert rec.pushed["tag"] == "stage2-r1" and rec.episodes_after == 12 + 2
    assert prog.dataset_source == {"repo": "alice/ds", "revision": ds_sha, "path": None}

    msta = card_at("alice/msta", "stage2-r1")["msta"]
    assert (msta["stage"], msta["round"]) == (2, 1)
    assert msta["dataset"] == {"repo": "alice/ds", "revision": ds_sha}
    assert msta["config"]["policy"] == {"path": "alice/msta@stage1"} and msta["config"]["rounds"] == 1
    # the card shows msta-correct's figures, which are msta-eval's on the same trials
    for m in ("0", "0.5"):
        norm = rec.eval[m]["normalized"]["per_terrain"]
        raw = rec.eval[m]["raw"]["per_terrain"]
        assert msta["metrics"][f"lin_tracking_vs_teacher@mask{m}"] == \
            pytest.approx(norm["average"]["lin_tracking"])
        assert msta["metrics"][f"total_vs_teacher@mask{m}"] == pytest.approx(norm["average"]["total"])
        assert msta["metrics"][f"survival@mask{m}"] == raw["average"]["survival"]
        assert msta["metrics"][f"lin_tracking_vs_teacher_ci95_low@mask{m}"] == \
            pytest.approx(norm["average"]["ci"]["lin_tracking"][0])
    assert msta["metrics"]["eval_trials"] == 2
    assert set(msta["eval_table"]) == {"flat", "stairs_up", "average"}
    assert msta["eval_table"]["average"]["trials"] == 2
    assert "total_vs_teacher@mask0.5" in msta["eval_table"]["average"]
    readme = Path(hub_api().hf_hub_download("alice/msta", "README.md", revision="stage2-r1"))
    assert ("msta-eval --policies teacher,alice/msta@stage2-r1 --scenarios token_removal --suite "
            "quick --trials 2 --terrains flat,stairs_up --levels 0 --episode_length_s 0.3 --seed 0"
            ) in readme.read_text().replace("\n", " ")

    # versions: both tags with their metrics; the tagged commits are the pushed ones
    v = versions("alice/msta")
    assert set(v.tags) == {"stage1", "stage2-r1"} and v.tags["stage2-r1"] == rec.pushed["commit"]
    by_tag = {t: c for c in v.commits for t in c.tags}
    assert by_tag["stage1"].metrics["train_loss"] > 0
    assert by_tag["stage2-r1"].metrics["total_vs_teacher@mask0"] == \
        msta["metrics"]["total_vs_teacher@mask0"]
    assert "average/total_vs_teacher@mask0.5" in by_tag["stage2-r1"].metrics
    captured = capsys.readouterr()
    assert ALICE not in captured.out + captured.err and BOB not in captured.out + captured.err


def test_failed_stage1_push_keeps_the_checkpoint(synthetic_dataset, server, tmp_path, monkeypatch,
                                                 capsys):
    monkeypatch.setenv("HF_TOKEN", BOB)
    with pytest.raises(SystemExit, match=r"(?s)saved at .*final.*alice/m@stage1.*403.*--resume=true"):
        main([f"--dataset={synthetic_dataset}", f"--output_dir={tmp_path / 'run'}", *FAST,
              "--push_to=alice/m"])
    assert MSTAPolicy.from_pretrained(tmp_path / "run" / "final").config.history == 5
    assert BOB not in capsys.readouterr().out
    # the same checkpoint pushed by its owner: a local dataset is recorded by its repo_id
    monkeypatch.setenv("HF_TOKEN", ALICE)
    cfg = parse_cli(TrainConfig, [f"--dataset={synthetic_dataset}", f"--output_dir={tmp_path / 'run'}",
                                  *FAST, "--resume=true", "--push_to=alice/m", "--push_private=true"],
                    prog="msta-train")
    train(cfg)
    msta = card_at("alice/m", "stage1")["msta"]
    assert msta["dataset"] == {"repo": "local/train_test", "revision": None}
    # a public card: the license, how to use it, and no path of this machine
    text = Path(hub_api().hf_hub_download("alice/m", "README.md", revision="stage1")).read_text()
    assert card_metadata(text)["license"] == "apache-2.0"
    assert 'load_policy("alice/m@stage1")' in text and "msta-eval --policies teacher,alice/m@stage1" in text
    assert str(tmp_path) not in text and str(synthetic_dataset) not in text
    assert msta["config"]["dataset"] == f"<local>/{synthetic_dataset.name}"
    assert "output_dir" not in msta["config"]
    assert hub_api().repo_info("alice/m").private
    with pytest.raises(HfHubHTTPError):  # private: anonymous reads are refused
        hub_api(token=False).repo_info("alice/m")


def test_local_source_and_bad_push_to(synthetic_dataset, tmp_path):
    src = dataset_source(str(synthetic_dataset), synthetic_dataset)
    assert src == {"repo": "local/train_test", "revision": None,
                   "path": str(synthetic_dataset.resolve())}
    for bad in ("alice", "alice/m@v1", "datasets/alice/m", "a b/c"):
        with pytest.raises(SystemExit, match="push_to"):
            parse_cli(TrainConfig, [f"--dataset={tmp_path}", f"--push_to={bad}"], prog="msta-train")
        with pytest.raises(SystemExit, match="push_to"):
            parse_cli(CorrectConfig, [f"--push_to={bad}"], prog="msta-correct")

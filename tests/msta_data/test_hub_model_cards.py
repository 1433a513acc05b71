"""Model cards in Hugging Face's conventions, used as a reader would: every shell command a
card shows runs as written (tiny sizes appended) against the real hub on 127.0.0.1, for
lerobot-train's ``pretrained_model`` and for an msta checkpoint; the front matter says what
huggingface_hub and LeRobot's own cards say; text from users and files renders inert."""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import markdown
import pytest
from huggingface_hub import ModelCard
from lerobot.configs.policies import PreTrainedConfig
from msta_test_helpers import hub_as

from msta.data.hub_cards import CardInfo, card_metadata
from msta.data.hub_cli import main as hub
from msta.data.hub_ids import hub_api
from msta.data.hub_model_card import LEROBOT_RUNTIME_FIELDS
from msta.data.hub_push import push
from msta.data.stats import load_stats
from msta.policies.factory import load_policy, make_policy
from msta.policies.msta.configuration_msta import MSTAConfig

BIN = Path(sys.executable).parent
SECRET = "alice-secret-0001"
#: Appended to a card's command so that it runs in seconds (the last value of an option wins).
TINY = {"lerobot-eval": ["--eval.n_episodes=1", "--eval.batch_size=1", "--env.terrains=[flat]",
                         "--env.episode_length_s=0.2"],
        "msta-eval": ["--trials", "1", "--episode_length_s", "0.2", "--terrains", "flat",
                      "--levels", "0", "--scenarios", "token_removal"]}


@pytest.fixture
def server(tmp_path, monkeypatch):
    with hub_as(tmp_path / "hub", monkeypatch) as srv:
        monkeypatch.setenv("MSTA_HUB_CACHE", str(tmp_path / "cache"))
        yield srv


def _env(tmp_path: Path, srv) -> dict[str, str]:
    return {**os.environ, "HF_ENDPOINT": srv.url, "HF_TOKEN": SECRET, "WANDB_MODE": "disabled",
            "HF_HOME": str(tmp_path / "hf"), "HF_LEROBOT_HOME": str(tmp_path / "lerobot"),
            "MSTA_HUB_CACHE": str(tmp_path / "cache"), "TORCH_HOME": str(tmp_path / "torch")}


def _run(argv: list[str], cwd: Path, env: dict[str, str]) -> str:
    proc = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=300,
                          check=False)
    assert proc.returncode == 0, (argv, proc.stdout[-2000:], proc.stderr[-3000:])
    return proc.stdout + proc.stderr


def run_card_commands(text: str, cwd: Path, env: dict[str, str]) -> list[str]:
    """Run every line of the card's bash block in ``cwd`` (shell words as written, the
    :data:`TINY` options appended); returns the programs run."""
    shell = re.search(r"```bash\n(.*?)```", text, re.DOTALL).group(1).splitlines()
    cwd.mkdir(parents=True, exist_ok=True)
    ran = []
    for line in shell:
        argv = shlex.split(line)
        exe = sys.executable if argv[0] == "python" else str(BIN / argv[0])
        _run([exe, *argv[1:], *TINY.get(argv[0], [])], cwd, env)
        ran.append(argv[0])
    return ran


def _card(repo: str, rev: str) -> tuple[dict, str]:
    text = Path(hub_api().hf_hub_download(repo, "README.md", revision=rev)).read_text()
    return card_metadata(text), text


def _body(text: str) -> str:
    return text.split("\n---\n", 1)[1]


@pytest.fixture(scope="module")
def lerobot_trained(tmp_path_factory, write_dataset) -> Path:
    """lerobot-train's ``pretrained_model`` after two steps of the tiny MSTA student."""
    tmp = tmp_path_factory.mktemp("lerobot_card")
    write_dataset(tmp / "ds", [30, 30, 30])
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled",
           "HF_HOME": str(tmp / "hf"), "HF_LEROBOT_HOME": str(tmp / "lerobot")}
    _run([str(BIN / "lerobot-train"), "--policy.type=msta", "--dataset.repo_id=alice/teacher",
          f"--dataset.root={tmp / 'ds'}", "--policy.device=cpu", "--steps=2", "--batch_size=4",
          "--num_workers=0", "--save_freq=2", f"--output_dir={tmp / 'out'}",
          "--policy.preset=tiny", "--policy.history=4", "--policy.num_threads=1"], tmp, env)
    return tmp / "out" / "checkpoints" / "last" / "pretrained_model"


def test_lerobot_train_checkpoint_card_recipe_runs(lerobot_trained, server, tmp_path, capsys):
    """msta-hub push of lerobot-train's folder: a card in LeRobot's conventions whose every
    command runs (pull, lerobot-eval on the pulled folder, msta-eval on the hub id)."""
    assert hub(["push", str(lerobot_trained), "alice/lr", "--tag", "v1"]) == 0
    out, err = capsys.readouterr()
    sha = out.strip()
    commit = hub_api().list_repo_commits("alice/lr")[0]
    assert commit.commit_id == sha
    assert commit.title == "Upload LeRobot msta checkpoint last/pretrained_model (8 files)"
    size = sum(p.stat().st_size for p in lerobot_trained.iterdir())
    assert re.fullmatch(rf"pushed 8 files \(([\d,]+) bytes\) to alice/lr@v1: "
                        rf"{re.escape(server.url)}/alice/lr/commit/{sha}\n", err), err
    assert int(re.search(r"\(([\d,]+) bytes", err).group(1).replace(",", "")) > size

    meta, text = _card("alice/lr", "v1")
    assert (meta["library_name"], meta["pipeline_tag"], meta["license"]) == (
        "lerobot", "robotics", "apache-2.0")
    assert {"lerobot", "robotics", "msta"} <= set(meta["tags"])
    assert meta["datasets"] == ["alice/teacher"]  # train_config.json's dataset.repo_id
    config = meta["msta"]["config"]
    assert config["type"] == "msta" and config["history"] == 4
    stored = json.loads((lerobot_trained / "config.json").read_text())
    assert set(LEROBOT_RUNTIME_FIELDS) <= set(stored)  # they were there, and are left out
    assert not set(LEROBOT_RUNTIME_FIELDS) & set(config)
    assert set(LEROBOT_RUNTIME_FIELDS) <= {f.name for f in
                                          PreTrainedConfig.__dataclass_fields__.values()}

    ran = run_card_commands(text, tmp_path / "reader", _env(tmp_path, server))
    assert ran == ["msta-hub", "lerobot-eval", "msta-eval"]
    assert (tmp_path / "reader" / "lr" / "policy_preprocessor.json").is_file()
    code = re.search(r"```python\n(.*?)```", text, re.DOTALL).group(1)
    scope: dict = {}
    for line in code.splitlines():
        if line.startswith(("from ", "policy = ")):
            exec(line, scope)  # noqa: S102 (the card's line, as written)
            if line.startswith("policy = "):
                assert scope["policy"].config.history == 4


def test_msta_checkpoint_card_front_matter_and_recipe(server, tmp_path, write_dataset):
    """An msta stage-2 checkpoint: datasets from msta's train_config.json, base_model from
    the stage-1 hub id it started from, model-index figures rounded with their 95 %
    intervals (read back by huggingface_hub), and every command of the card runs."""
    data = tmp_path / "ds"
    write_dataset(data, [8, 8])
    policy = make_policy(MSTAConfig.from_preset("tiny"), load_stats(data))
    stage1 = policy.save_pretrained(tmp_path / "stage1")
    push(stage1, "alice/m", tag="stage1")
    ckpt = policy.save_pretrained(tmp_path / "round_1")
    (ckpt / "train_config.json").write_text(json.dumps(
        {"dataset": "datasets/alice/a1-teacher@v3.0", "policy": {"path": "alice/m@stage1"},
         "output_dir": str(tmp_path)}))
    metrics = {"survival@mask0": 0.6000000000000001, "survival_ci95_low@mask0": 0.31,
               "survival_ci95_high@mask0": 0.8321999, "eval_trials": 10}
    push(ckpt, "alice/m", tag="stage2-r1", card=CardInfo(stage=2, round=1, metrics=metrics))
    meta, text = _card("alice/m", "stage2-r1")
    assert (meta["library_name"], meta["pipeline_tag"]) == ("msta", "robotics")
    assert meta["datasets"] == ["alice/a1-teacher"] and meta["base_model"] == "alice/m"
    assert "- **Fine-tuned from**: `alice/m@stage1`" in text
    index = re.search(r"model-index:.*?\nmsta:", text, re.DOTALL).group(0)
    assert "0.6000000000000001" not in index
    results = ModelCard(text).data.eval_results
    assert [(r.metric_type, r.metric_value, r.metric_args) for r in results] == [
        ("survival@mask0", 0.6, {"ci95_low": 0.31, "ci95_high": 0.8322})]
    assert results[0].task_type == "robotics" and results[0].metric_name == \
        "survival@mask0 (95 % interval 0.31 to 0.8322)"
    assert meta["msta"]["metrics"]["survival@mask0"] == 0.6000000000000001  # every number

    ran = run_card_commands(text, tmp_path / "reader", _env(tmp_path, server))
    assert ran == ["msta-eval", "python", "lerobot-eval"]
    assert (tmp_path / "reader" / "msta_lerobot" / "policy_preprocessor.json").is_file()
    assert load_policy("alice/m@stage2-r1").config.type == "msta"


HOSTILE = {"script": "<script>alert(1)</script>", "img": "<img src=x onerror=alert(2)>",
           "heading": "# Pwned", "link": "[click](https://evil.example/x)",
           "auto": "see https://evil.example/y"}


def test_text_from_users_and_files_renders_inert(server, tmp_path, write_dataset, capsys):
    """Metric, row and column names, the dataset revision, a policy name and a terrain from
    msta-eval's file: the rendered card has no tag, heading or link of theirs, and shows
    each as the text it is."""
    data = tmp_path / "ds"
    write_dataset(data, [8])
    ckpt = make_policy(MSTAConfig.from_preset("tiny"), load_stats(data)).save_pretrained(
        tmp_path / "ckpt")
    names = list(HOSTILE.values())
    (tmp_path / "table.json").write_text(json.dumps(
        {names[i]: {names[-1 - i]: 0.5, "trials": 3} for i in range(len(names))}))
    assert hub(["push", str(ckpt), "alice/x", "--tag", "t1", "--eval_json",
                str(tmp_path / "table.json"), "--dataset_repo", "alice/d",
                "--dataset_revision", HOSTILE["script"] + " " + HOSTILE["heading"]]) == 0
    fixture = json.loads((Path(__file__).parents[1] / "eval" / "fixtures" /
                          "metrics_before_history.json").read_text())
    fixture["policies"][1]["name"] = HOSTILE["img"]
    for run in fixture["runs"]:
        run["policy"] = HOSTILE["img"] if run["policy"] == "msta" else run["policy"]
        run["condition"] = f"{run['condition']} {HOSTILE['link']}"
    fixture["config"]["terrains"] = [HOSTILE["heading"], HOSTILE["auto"]]
    (tmp_path / "metrics.json").write_text(json.dumps(fixture))
    assert hub(["push", str(ckpt), "alice/x", "--tag", "t2", "--eval_json",
                str(tmp_path / "metrics.json")]) == 0
    capsys.readouterr()
    for tag in ("t1", "t2"):
        _, text = _card("alice/x", tag)
        html = markdown.markdown(_body(text), extensions=["tables", "fenced_code"])
        assert len(re.findall(r"<h1", html)) == 1, tag  # the title only
        for bad in ("<script", "<img", "<a ", "evil.example/x\"", "href"):
            assert bad not in html, (tag, bad)
        shown = re.sub(r"<[^>]+>", "", html).replace("&lt;", "<").replace("&gt;", ">") \
            .replace("&amp;", "&").replace("&#58;", ":").replace("&#46;", ".")
        want = names if tag == "t1" else [HOSTILE["img"], HOSTILE["link"], HOSTILE["heading"]]
        for name in want:
            assert name in shown, (tag, name)

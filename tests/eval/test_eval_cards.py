"""``msta-hub push --eval_json`` with msta-eval's own metrics.json: the card shows the
student's headline figures per scenario and condition with their 95 % intervals and trial
counts, equal to :func:`msta.eval.metrics.headline` of the same runs; an eval file msta cannot
read is one line and exit status 1. Against the real hub server on 127.0.0.1."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest
from msta_test_helpers import hub_as

from msta.data.cli import parse_config
from msta.data.figures import fmt_ci
from msta.data.hub_cards import card_metadata
from msta.data.hub_cli import main as hub
from msta.data.hub_eval import HEADLINE_FIGURES
from msta.data.hub_ids import hub_api
from msta.eval.eval_config import EvalConfig
from msta.eval.evaluation import evaluate
from msta.eval.metrics import headline


@pytest.fixture(scope="module")
def evaluated(tiny_ckpt, tmp_path_factory) -> tuple[Path, dict]:
    """msta-eval of the teacher and the tiny student: the quick suite's three test masks and
    four windows."""
    out = tmp_path_factory.mktemp("eval_card")
    cfg = EvalConfig(policies=f"teacher,{tiny_ckpt}", scenarios="token_removal,history",
                     terrains="flat,stairs_up", levels="0", trials=2, episode_length_s=0.5,
                     output_dir=str(out), progress=False)
    return out / "metrics.json", evaluate(cfg)


@pytest.fixture
def hub_env(tmp_path, monkeypatch):
    with hub_as(tmp_path / "hub", monkeypatch) as srv:
        yield srv


def _card(repo: str, rev: str) -> tuple[dict, str]:
    text = Path(hub_api().hf_hub_download(repo, "README.md", revision=rev)).read_text()
    return card_metadata(text), text


def test_the_card_shows_msta_evals_headline_figures(evaluated, tiny_ckpt, hub_env, capsys):
    path, metrics = evaluated
    assert hub(["push", str(tiny_ckpt), "alice/m", "--tag", "v1", "--eval_json", str(path)]) == 0
    assert "warning" not in capsys.readouterr().err  # the student was found by its files
    meta, text = _card("alice/m", "v1")
    msta = meta["msta"]
    student = next(p["name"] for p in metrics["policies"] if p["kind"] == "student")
    runs = [r for r in metrics["runs"] if r["policy"] == student]
    assert len(runs) == 3 + 4 and all(r["status"] == "ok" for r in runs)  # masks, windows
    rows = {m.group(1): m.group(2).split(" | ") for m in
            re.finditer(r"^\| (\S+ [^|]+?) \| (.*) \|$", text, re.MULTILINE)}
    for run in runs:
        avg = headline(run)["average"]
        row = f"{run['scenario']} {run['condition']}"
        table = msta["eval_table"][row]
        assert table["trials"] == avg["trials"] == 2
        shown = rows[row]
        assert shown[-1] == "2"
        for i, (name, _, _) in enumerate(HEADLINE_FIGURES):
            assert table[name] == pytest.approx(avg[name], rel=1e-12)
            assert [table[f"{name}_ci95_low"], table[f"{name}_ci95_high"]] == \
                pytest.approx(avg["ci"][name], rel=1e-12)
            assert shown[i] == fmt_ci(avg[name], avg["ci"][name])  # '0.85 ±0.10' / '(lo–hi)'
    for m in ("0", "0.25", "0.5"):  # the test masks as flat metrics, as on a stage-2 card
        run = next(r for r in runs if r["scenario"] == "token_removal"
                   and f"{r['value']:g}" == m)
        avg = headline(run)["average"]
        assert msta["metrics"][f"survival@mask{m}"] == pytest.approx(avg["survival"])
        assert msta["metrics"][f"total_vs_teacher_ci95_high@mask{m}"] == \
            pytest.approx(avg["ci"]["total_vs_teacher"][1])
    assert msta["metrics"]["eval_trials"] == 2
    assert msta["evaluation"]["policy"] == student and msta["evaluation"]["trials"] == 2
    assert "2 trials (episodes) per row." in text and "(1 per terrain)" in text

    # the card's msta-eval command runs the same trials on the pushed checkpoint
    cmd = re.search(r"`(msta-eval --policies teacher,alice/m@v1 [^`]*)`", text).group(1)
    again = parse_config(EvalConfig, cmd.split()[1:], "msta-eval").resolved()
    for key in ("suite", "scenarios", "trials", "terrains", "levels", "episode_length_s",
                "num_envs", "seed", "noise", "randomization", "heading_commands"):
        assert again[key] == metrics["config"][key], key
    assert again["teacher"]["type"] == metrics["config"]["teacher"]["type"]

    assert hub(["versions", "alice/m"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"lin_tracking_vs_teacher@mask0=\S+", out)


def _write(path: Path, data) -> Path:
    path.write_text(data if isinstance(data, str) else json.dumps(data))
    return path


def test_eval_files_msta_cannot_read_are_one_line_errors(evaluated, tiny_ckpt, tmp_path,
                                                         hub_env, capsys):
    path, metrics = evaluated
    student = metrics["policies"][1]["name"]
    two = dict(metrics, policies=metrics["policies"] + [
        dict(metrics["policies"][1], name="other", revision="0" * 12)],
        runs=metrics["runs"] + [dict(r, policy="other") for r in metrics["runs"]
                                if r["policy"] == student])
    cases = {
        "not JSON": (_write(tmp_path / "a.json", "{oops"), "cannot read it"),
        "a list": (_write(tmp_path / "b.json", [1, 2]), "holds list"),
        "empty": (_write(tmp_path / "c.json", {}), "holds an empty object"),
        "a string metric": (_write(tmp_path / "d.json", {"loss": "low"}), "'loss' is not a"),
        "an old format": (_write(tmp_path / "e.json", {**metrics, "msta_eval_version": 1}),
                          "format 1; this msta reads format 2"),
        "no runs": (_write(tmp_path / "f.json", {"msta_eval_version": 2, "config": {}}),
                    "not a complete msta-eval metrics.json"),
        "a teacher only": (_write(tmp_path / "g.json", dict(metrics, policies=metrics[
            "policies"][:1])), "no student was evaluated"),
    }
    other = shutil.copytree(tiny_ckpt, tmp_path / "other_ckpt")
    (other / "extra.json").write_text("{}")  # files unlike the evaluated checkpoint's
    for what, (bad, message) in cases.items():
        assert hub(["push", str(tiny_ckpt), "alice/bad", "--eval_json", str(bad)]) == 1, what
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and message in err, (what, err)
    # two students, neither evaluated from these files: which one is asked for
    assert hub(["push", str(other), "alice/bad", "--eval_json",
                str(_write(tmp_path / "h.json", two))]) == 1
    assert "pass --eval_policy=NAME (one of" in capsys.readouterr().err
    assert hub(["push", str(other), "alice/ok", "--eval_json", str(tmp_path / "h.json"),
                "--eval_policy", "other", "--tag", "v1"]) == 0
    assert _card("alice/ok", "v1")[0]["msta"]["evaluation"]["policy"] == "other"
    # one student whose files differ: its figures, with a warning that says so
    assert hub(["push", str(other), "alice/ok", "--eval_json", str(path), "--tag", "v2"]) == 0
    assert "whose files differ from" in capsys.readouterr().err
    # a dataset card takes no policy's figures
    assert hub(["push-dataset", str(tmp_path), "alice/ds", "--eval_json", str(path)]) == 1
    assert "describes policies; give it to msta-hub push" in capsys.readouterr().err

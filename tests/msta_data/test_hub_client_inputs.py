"""What msta-hub's client refuses before it talks to a hub, in one line with exit status 1:
an --eval_json that is not a regular file of a sane size or not a well-formed metrics.json in
any of its parts, a folder to push holding a symbolic link (it would publish the link's
target), and an --endpoint where nothing answers. Against the real server on 127.0.0.1."""

from __future__ import annotations

import copy
import json
import math
import os
import socket
from pathlib import Path

import pytest
from huggingface_hub.errors import RepositoryNotFoundError
from msta_test_helpers import hub_as

from msta.data.hub_cards import CardInfo
from msta.data.hub_cli import main as hub
from msta.data.hub_eval import EvalJsonError, read_eval_json
from msta.data.hub_ids import hub_api
from msta.data.hub_model_card import model_card
from msta.data.hub_push import push, push_dataset
from msta.data.inside import PathOutsideRootError

FIXTURE = Path(__file__).resolve().parents[1] / "eval" / "fixtures" / "metrics_before_history.json"


@pytest.fixture
def server(tmp_path, monkeypatch):
    with hub_as(tmp_path / "hub", monkeypatch) as srv:
        yield srv


def _checkpoint(path: Path) -> Path:
    path.mkdir(parents=True)
    (path / "config.json").write_text(json.dumps({"type": "gru"}))
    (path / "model.safetensors").write_bytes(b"\0" * 64)
    return path


def _one_line_error(capsys, *needles: str) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, (needle, err)
    return err


def _not_pushed(repo: str) -> None:
    with pytest.raises(RepositoryNotFoundError):
        hub_api().repo_info(repo)


# ----- --eval_json -----------------------------------------------------------------------
@pytest.mark.timeout(60)
def test_eval_json_reads_only_a_regular_file_of_a_sane_size(server, tmp_path, capsys):
    ckpt = _checkpoint(tmp_path / "ckpt")
    fifo = tmp_path / "eval.fifo"
    os.mkfifo(fifo)  # nobody writes: reading would wait for ever
    big = tmp_path / "big.json"
    with open(big, "wb") as f:  # sparse: 17 MiB of zeros (no memory, no disk)
        f.truncate(17 << 20)
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000)  # json's recursion limit, not a crash
    for path, why in ((fifo, "not a regular file"), (Path("/dev/zero"), "not a regular file"),
                      (tmp_path, "not a regular file"), (big, "larger than 16,777,216 bytes"),
                      (deep, "cannot read it as JSON (RecursionError"),
                      (tmp_path / "missing.json", "cannot read it (No such file")):
        assert hub(["push", str(ckpt), "alice/m", "--eval_json", str(path)]) == 1, path
        _one_line_error(capsys, f"--eval_json {path}: {why}")
        assert hub(["push", str(ckpt), "alice/m", "--config_json", str(path)]) == 1, path
        _one_line_error(capsys, f"--config_json {path}: {why}")
    _not_pushed("alice/m")


def _small_metrics() -> dict:
    """A real msta-eval metrics.json cut to what a card reads: one student's two runs, the
    terrain average of the three headline figures, the reference's trial count."""
    data = json.loads(FIXTURE.read_text())
    keep = ("lin_tracking", "total", "survival")
    runs = []
    for run in [r for r in data["runs"] if r["policy"] == "msta"][:2]:
        cut = {k: run[k] for k in ("policy", "scenario", "condition", "value", "status")}
        for figure in ("raw", "normalized"):
            avg = run[figure]["per_terrain"]["average"]
            cut[figure] = {"per_terrain": {"average": {
                **{k: avg[k] for k in (*keep, "trials") if k in avg},
                "ci": {k: avg["ci"][k] for k in keep if k in avg}}}}
        runs.append(cut)
    ref = data["reference"]
    return {"msta_eval_version": 2, "config": data["config"], "policies": data["policies"],
            "terrains": ["stairs_up"], "runs": runs,
            "reference": {"revision": ref["revision"],
                          "per_terrain": {"stairs_up": {"trials": 20}}}}


def _paths(node, at=()):
    """Every (container path, key) in a JSON tree."""
    items = node.items() if isinstance(node, dict) else enumerate(node) \
        if isinstance(node, list) else ()
    for key, child in items:
        yield at, key
        yield from _paths(child, (*at, key))


def _get(node, at):
    for key in at:
        node = node[key]
    return node


def test_every_malformed_part_of_a_metrics_json_is_a_one_line_error(tmp_path):
    """Each value of a real metrics.json replaced by each other JSON type (or removed): the
    figures are read, or refused with one EvalJsonError line; never another exception."""
    good = _small_metrics()
    path = tmp_path / "metrics.json"
    path.write_text(json.dumps(good))
    figures = read_eval_json(path, policy="msta", ref="alice/m@v1")
    assert figures.table and figures.metrics
    wrong = (None, True, -1, 1.5, math.nan, "x", [], {}, [1], {"x": 1})
    refused, read = 0, 0
    for at, key in list(_paths(good)):
        for value in (*wrong, KeyError):
            data = copy.deepcopy(good)
            if value is KeyError:
                if not isinstance(key, str):
                    continue
                del _get(data, at)[key]
            else:
                _get(data, at)[key] = value
            path.write_text(json.dumps(data))
            try:
                got = read_eval_json(path, policy="msta", ref="alice/m@v1")
            except EvalJsonError as e:
                assert len(str(e).splitlines()) == 1 and str(path) in str(e), (at, key, value)
                refused += 1
                continue
            model_card(CardInfo(metrics=got.metrics, eval_table=got.table,
                                eval_note=got.note), "alice/m", "v1")  # and a card is made
            read += 1
    assert refused > 200 and read > 200  # both outcomes were reached


# ----- symbolic links ----------------------------------------------------------------------
def test_push_and_push_dataset_refuse_a_symbolic_link(server, tmp_path, write_dataset, capsys):
    secret = tmp_path / "tokens"
    secret.write_text("alice:alice-secret-0001\n")
    ckpt = _checkpoint(tmp_path / "ckpt")
    (ckpt / "extra").mkdir()
    (ckpt / "extra" / "notes.txt").symlink_to(secret)
    assert hub(["push", str(ckpt), "alice/m"]) == 1
    _one_line_error(capsys, "extra/notes.txt", "symbolic links")
    with pytest.raises(PathOutsideRootError, match="extra/notes.txt"):
        push(ckpt, "alice/m")
    _not_pushed("alice/m")
    (ckpt / "extra" / "notes.txt").unlink()
    (ckpt / "weights").symlink_to(ckpt / "extra")  # a link to a folder inside counts too
    assert hub(["push", str(ckpt), "alice/m"]) == 1
    _one_line_error(capsys, "weights")

    root = tmp_path / "ds"
    write_dataset(root, [3])
    (root / "meta" / "token.json").symlink_to(secret)
    assert hub(["push-dataset", str(root), "alice/ds"]) == 1
    _one_line_error(capsys, "meta/token.json", "symbolic links")
    with pytest.raises(PathOutsideRootError, match="meta/token.json"):
        push_dataset(root, "alice/ds")
    with pytest.raises(RepositoryNotFoundError):
        hub_api().repo_info("alice/ds", repo_type="dataset")


# ----- unreachable endpoint ----------------------------------------------------------------
def test_an_unreachable_endpoint_is_one_line_naming_it(tmp_path, capsys):
    with socket.socket() as s:  # a port that was free a moment ago: nothing listens there
        s.bind(("127.0.0.1", 0))
        url = f"http://127.0.0.1:{s.getsockname()[1]}"
    ckpt = _checkpoint(tmp_path / "ckpt")
    for argv in (["push", str(ckpt), "alice/m"], ["pull", "alice/m@v1", str(tmp_path / "p")],
                 ["versions", "alice/m"]):
        assert hub([*argv, "--endpoint", url]) == 1, argv
        _one_line_error(capsys, f"msta-hub {argv[0]}: error: cannot reach the hub at {url}")
    assert not (tmp_path / "p").exists()

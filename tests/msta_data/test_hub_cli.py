"""msta-hub's command line: the old argparse spellings still parse to the same configs, and
`msta-hub versions` lines stay short (the hub round trips are in test_hub_client.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from msta.data.hub_cli import PullConfig, PushConfig, ServeConfig, main, parse_command
from msta.data.hub_versions import RepoVersions, Version


def test_bare_words_dashes_and_bare_flags_parse_as_before():
    name, cfg = parse_command(["push", "runs/s1", "alice/m", "--tag", "stage1-r0", "--move-tag",
                               "--stage", "1", "--dataset-repo", "alice/d"])
    assert name == "push" and isinstance(cfg, PushConfig)
    assert (cfg.checkpoint_dir, cfg.repo_id, cfg.tag, cfg.move_tag) == (
        Path("runs/s1"), "alice/m", "stage1-r0", True)
    assert (cfg.stage, cfg.dataset_repo, cfg.private) == (1, "alice/d", False)
    # the same with the option names --help shows
    assert parse_command(["push", "--checkpoint_dir=runs/s1", "--repo_id=alice/m",
                          "--tag=stage1-r0", "--move_tag=true", "--stage=1",
                          "--dataset_repo=alice/d"])[1] == cfg
    _, pulled = parse_command(["-v", "pull", "--overwrite", "datasets/alice/d@v3.0", "out"])
    assert pulled == PullConfig(spec="datasets/alice/d@v3.0", dest=Path("out"), overwrite=True,
                                verbose=True)


def test_serve_takes_repeated_tokens_and_orgs_with_commas(tmp_path):
    _, cfg = parse_command(["serve", "--root", str(tmp_path), "--token", "alice:s1",
                            "--token=bob:s2", "--org", "lab:alice,bob", "--max-body-bytes", "99"])
    assert isinstance(cfg, ServeConfig)
    assert cfg.token == ["alice:s1", "bob:s2"] and cfg.org == ["lab:alice,bob"]
    assert cfg.limits().max_body_bytes == 99 and cfg.limits().read_timeout_s == 60.0


@pytest.mark.parametrize("argv, message", [
    ([], "give a command: serve, push, push-dataset, pull, versions"),
    (["pul", "a/b", "x"], "unknown command 'pul' (did you mean pull?)"),
    (["pull", "a/b"], "DEST is required"),
    (["pull", "a/b", "x", "y"], "unexpected argument 'y' (takes SPEC DEST)"),
    (["serve"], "--root is required"),
    (["serve", "--root=x", "--max_connections=0"], "max_connections must be positive"),
])
def test_bad_command_lines_are_one_line_exit_2(argv, message, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("msta-hub") and message in err, err


def test_overview_lists_every_command(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    for name in ("serve", "push", "push-dataset", "pull", "versions"):
        assert f"\n  {name} " in out
    assert "msta-hub pull alice/msta-a1@stage1-r0 ckpt/stage1" in out


def test_versions_text_keeps_lines_short():
    metrics = {f"mask{m}/scenario_{s}/tracking_lin": 0.123 * s for m in range(4) for s in range(12)}
    commits = [Version("a" * 40, "push " + "x" * 200, "2026-01-01T00:00:00+00:00", ["alice"],
                       ["stage1-r0"], ["main"], metrics),
               Version("b" * 40, "push", "2025-12-31T00:00:00+00:00", [], [], [], {"total": 0.9})]
    text = RepoVersions("alice/m", "model", {}, {}, commits).to_text()
    lines = text.splitlines()
    assert max(map(len, lines)) <= 100
    assert lines[1].startswith("a" * 12) and lines[1].endswith("[branch main, tag stage1-r0]")
    assert len(lines) == 1 + (1 + 3) + (1 + 1)  # a header, each commit and its metric lines
    shown = sum(line.count("=") for line in lines[2:4])
    assert lines[4].strip() == f"... {len(metrics) - shown} more metrics (--json lists them all)"
    assert lines[-1].strip() == "total=0.9"


def test_serve_sets_every_per_user_budget_from_its_command_line(tmp_path):
    _, cfg = parse_command(["serve", "--root", str(tmp_path), "--max_user_connections=3",
                            "--max_user_body_bytes=1000", "--max_user_tickets=7",
                            "--max_tickets=9"])
    limits = cfg.limits()
    assert (limits.max_user_connections, limits.max_user_body_bytes, limits.max_user_tickets,
            limits.max_tickets) == (3, 1000, 7, 9)

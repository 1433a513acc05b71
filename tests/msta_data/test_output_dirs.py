"""A command deletes only what it wrote (msta.data.output_dirs): the demo, the device check
and the benchmarks refuse an --output_dir holding someone else's files, in one line,
deleting nothing."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from msta.data.output_dirs import MARKER, OutputDirError, claim_output_dir, clear_output_dir


def test_a_new_or_empty_folder_is_claimed_and_marked(tmp_path):
    for path in (tmp_path / "new" / "deep", tmp_path / "empty"):
        (tmp_path / "empty").mkdir(exist_ok=True)
        assert claim_output_dir(path, "msta-x") == path
        assert (path / MARKER).is_file()


def test_only_a_marked_folder_is_cleared(tmp_path):
    out = claim_output_dir(tmp_path / "run", "msta-x")
    (out / "sub").mkdir()
    (out / "sub" / "f").write_text("mine")
    (out / "g").write_text("mine")
    clear_output_dir(out, "msta-x")
    assert sorted(p.name for p in out.iterdir()) == [MARKER]


def test_a_folder_with_foreign_files_is_refused_and_kept(tmp_path):
    user = tmp_path / "mine"
    (user / "src").mkdir(parents=True)
    (user / "src" / "f").write_text("hi")
    with pytest.raises(OutputDirError, match=r"--output_dir=.*mine holds files that msta-x did "
                                             r"not write \(no \.msta-output\)"):
        clear_output_dir(user, "msta-x")
    assert (user / "src" / "f").read_text() == "hi" and not (user / MARKER).exists()


def test_a_file_or_a_link_is_not_an_output_folder(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    (tmp_path / "link").symlink_to(tmp_path / "elsewhere", target_is_directory=True)
    for path in (f, tmp_path / "link"):
        with pytest.raises(OutputDirError, match="is not a folder"):
            claim_output_dir(path, "msta-x")
    assert f.read_text() == "x"


def test_an_old_run_is_recognised_by_its_entries(tmp_path):
    legacy, sign = frozenset({"stage1", "eval", "verdict.txt"}), frozenset({"verdict.txt"})
    old = tmp_path / "old"
    (old / "stage1").mkdir(parents=True)
    (old / "verdict.txt").write_text("VERDICT")
    clear_output_dir(old, "msta-demo", legacy=legacy, sign=sign)
    assert sorted(p.name for p in old.iterdir()) == [MARKER]
    (old / "notes.txt").write_text("a user's")
    (old / MARKER).unlink()
    with pytest.raises(OutputDirError):
        clear_output_dir(old, "msta-demo", legacy=legacy, sign=sign)
    common = tmp_path / "outputs"  # other commands' outputs with names the demo also writes
    (common / "eval").mkdir(parents=True)
    (common / "stage1").mkdir()
    with pytest.raises(OutputDirError, match="did not write"):
        clear_output_dir(common, "msta-demo", legacy=legacy, sign=sign)
    assert (common / "eval").is_dir()


def test_another_commands_folder_is_refused(tmp_path):
    out = claim_output_dir(tmp_path / "run", "msta-x")
    (out / "result").write_text("x's")
    with pytest.raises(OutputDirError, match="holds msta-x's outputs; choose another"):
        clear_output_dir(out, "msta-y")
    assert (out / "result").read_text() == "x's"


@pytest.mark.parametrize("module", ["msta.eval.apps.demo", "msta.eval.apps.device_check",
                                    "msta.eval.bench.learn", "msta.eval.bench.scale",
                                    "msta.eval.bench.scale_train"])
def test_the_commands_refuse_a_users_folder_in_one_line(tmp_path, module):
    """What a hostile review did: --output_dir=<a folder of one's own> (or '.') deleted it."""
    user = tmp_path / "x"
    (user / "src").mkdir(parents=True)
    (user / "src" / "f").write_text("hi")
    for out, cwd in ((user, tmp_path), (Path("."), user), (user / "src" / "f", tmp_path)):
        res = subprocess.run([sys.executable, "-m", module, f"--output_dir={out}"], cwd=cwd,
                             capture_output=True, text=True, timeout=300, check=False)
        err = res.stderr.strip()
        assert res.returncode == 2 and "\n" not in err and "Traceback" not in err, err
        assert "--output_dir=" in err and ("did not write" in err or "not a folder" in err)
        assert (user / "src" / "f").read_text() == "hi"

"""The one path check: nothing under a root leads outside it through a symbolic link."""

from __future__ import annotations

import pytest

from msta.data.inside import PathOutsideRootError, files_under, inside, links_under


def _tree(tmp_path):
    root, outside = tmp_path / "root", tmp_path / "outside"
    (root / "a").mkdir(parents=True)
    outside.mkdir()
    (root / "a" / "f.txt").write_text("in")
    (outside / "secret").write_text("token")
    return root, outside


def test_inside_accepts_plain_paths_and_paths_not_yet_written(tmp_path):
    root, _ = _tree(tmp_path)
    assert inside(root, "a/f.txt") == root / "a" / "f.txt"
    assert inside(root, "a/new/file") == root / "a" / "new" / "file"
    (root / "a" / "alias").symlink_to(root / "a" / "f.txt")  # a link that stays inside
    assert inside(root, "a/alias") == root / "a" / "alias"


@pytest.mark.parametrize("rel", ["link", "link/secret", "../outside/secret", "dirlink/x"])
def test_inside_refuses_links_and_dot_dots_leading_out(tmp_path, rel):
    root, outside = _tree(tmp_path)
    (root / "link").symlink_to(outside)
    (root / "dirlink").symlink_to(outside)
    with pytest.raises(PathOutsideRootError, match="symbolic link leading outside the dataset"):
        inside(root, rel, what="dataset")


def test_files_under_never_follows_links(tmp_path):
    root, outside = _tree(tmp_path)
    (root / "a" / "token").symlink_to(outside / "secret")
    (root / "folder").symlink_to(outside)
    assert links_under(root) == ["a/token", "folder"]
    with pytest.raises(PathOutsideRootError, match=r"a/token, folder.*replace them"):
        files_under(root, what="folder to push")
    assert list(files_under(root, links="skip")) == ["a/f.txt"]
    with pytest.raises(ValueError, match="links='follow'"):
        files_under(root, links="follow")

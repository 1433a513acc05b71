"""msta.data.revision: the one content hash behind teacher, checkpoint and weight revisions."""

from __future__ import annotations

import hashlib

from msta.data.revision import content_revision, file_parts


def test_revision_is_a_short_sha256_of_the_parts_in_order():
    want = hashlib.sha256(b"gait" + b"{}").hexdigest()[:12]
    assert content_revision(["gait", b"{}"]) == want
    assert content_revision(["gait", b"{}"], prefix="gait") == f"gait-{want}"
    assert content_revision([b"{}", "gait"]) != want


def test_file_parts_cover_names_and_bytes(tmp_path):
    (tmp_path / "sub").mkdir()
    (tmp_path / "b.bin").write_bytes(b"yz")
    (tmp_path / "sub" / "a.json").write_text("x")
    assert list(file_parts(tmp_path)) == [b"b.bin", b"yz", b"sub/a.json", b"x"]
    assert list(file_parts(tmp_path / "sub" / "a.json")) == [b"a.json", b"x"]
    before = content_revision(file_parts(tmp_path))
    (tmp_path / "b.bin").rename(tmp_path / "c.bin")  # same bytes, another name
    assert content_revision(file_parts(tmp_path)) != before
    (tmp_path / "c.bin").rename(tmp_path / "b.bin")
    assert content_revision(file_parts(tmp_path)) == before
    (tmp_path / "b.bin").write_bytes(b"yZ")
    assert content_revision(file_parts(tmp_path)) != before

"""eval.label_check: the teacher-takeover check of stage 2's labels."""

from __future__ import annotations

import pytest

from eval.label_check import label_check, main, render


def test_rows_share_robots_and_the_teacher_is_the_reference(tiny_ckpt, capsys):
    rows = label_check(str(tiny_ckpt), robots=3, student_s=0.2, total_s=0.4, max_level=0)
    assert list(rows) == ["teacher", "student", "takeover shadow", "takeover follow",
                          "takeover reset"]
    assert rows["teacher"]["lin_tracking"] == pytest.approx(1.0)
    assert all(r["robots"] == 3 and 0.0 <= r["survival"] <= 1.0 for r in rows.values())
    lo, hi = rows["student"]["survival_ci"]
    assert lo <= rows["student"]["survival"] <= hi
    # the takeovers differ from the student alone: the teacher drove their last 0.2 s
    assert rows["takeover shadow"]["lin_tracking"] != rows["student"]["lin_tracking"]
    table = render(rows)
    assert table.count("\n") == 6 and "| takeover follow | 3 |" in table


@pytest.mark.parametrize("args, message", [
    (["--policy", "/no/such/ckpt"], "is not a checkpoint directory"),
    (["--student_s", "5", "--total_s", "3"], "need 0 < student_s < total_s"),
    (["--robots", "0"], "--robots must be >= 1"),
])
def test_clear_errors(args, message, tiny_ckpt, capsys):
    argv = args if args[0] == "--policy" else ["--policy", str(tiny_ckpt), *args]
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2 and message in capsys.readouterr().err

"""Small things of the command line a user meets: ``-o`` for ``--out``, a progress bar
that never moves back."""

from __future__ import annotations

import io

import pytest

from vectoradjust.cli.commands import build_parser
from vectoradjust.cli.progress import ProgressBar


@pytest.mark.parametrize("argv", [
    ["adjust", "p.toml", "-o", "D"], ["compare", "p.toml", "-o", "D"], ["demo", "-o", "D"],
    ["qa", "p.toml", "-o", "D"], ["adjust-many", "a.toml", "-o", "D"],
    ["study", "gcp", "p.toml", "-o", "D"], ["study", "identification", "-o", "D"],
])
def test_o_is_short_for_out(argv):
    args = build_parser().parse_args(argv)
    assert args.out == "D"


def test_progress_bar_never_moves_back():
    out = io.StringIO()
    bar = ProgressBar("adjust", stream=out)
    bar(0.5, "iteration 1")
    bar(0.3, "database offsets: iteration 1")  # a pass that restarts lower
    bar(0.6, "done")
    lines = out.getvalue().splitlines()
    assert [line.split("]")[1].split("%")[0].strip() for line in lines] == ["50.0", "50.0",
                                                                           "60.0"]

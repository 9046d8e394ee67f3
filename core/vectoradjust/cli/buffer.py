"""The buffer test (Goodchild & Hunter 1997) on the command line and against truth lines.

``vectoradjust buffer-test TESTED REFERENCE --widths 1,2,5`` prints the share of the
tested lines' length inside buffers of the reference lines. With a ``[truth]`` table
(true centrelines) in the project, ``adjust`` and ``compare`` add the share of each
database's lines inside 1 m and 2 m (or ``widths``) of the truth before and after the
adjustment to ``summary.json`` (``databases[].truth.buffer``), measured with the exact
round buffers (``buffer-test --exact``), linear in the size of the data.
"""

from __future__ import annotations

import csv
from pathlib import Path

from vectoradjust.files.truth import parse_widths, project_truth, read_lines, truth_buffer

__all__ = ["add_parser", "cmd_buffer_test", "read_lines", "truth_buffer", "parse_widths",
           "project_truth", "TruthBeforeAlongside"]


class TruthBeforeAlongside:
    """The ``[truth]`` tests' half before the adjustment
    (:func:`vectoradjust.files.truth.truth_before`: the database lines inside the true
    lines' buffers, the database vertices' distances to them) computed by a forked
    process while the parent adjusts (the second core is idle during the solve).

    :meth:`result` gives it to ``truth_buffer(before=...)`` and
    ``truth_tables(before=...)``, which then measure only the adjusted coordinates.
    Without a child (no ``fork``, ``VECTORADJUST_WORKERS=1``) or when it failed,
    :meth:`result` is None and they measure both halves as without it: the same values.

    Parameters
    ----------
    data : vectoradjust.model.ProjectData
        The project's inputs, as read.
    truth_path : str
        The true centrelines (``[truth] path``).
    widths : list of float
        The buffer widths.
    preload : vectoradjust.cli.background.Preload, optional
        Imports running in a thread: waited for before the fork (no module half
        imported in the child).
    """

    def __init__(self, data, truth_path, widths, preload=None) -> None:
        from vectoradjust.cli.background import Background
        from vectoradjust.files.truth import truth_before

        if preload is not None:
            preload.wait()
        self.job = Background(truth_before, data, truth_path, widths)

    def result(self, progress=None):
        """The :class:`vectoradjust.files.truth.TruthBefore` of the child (waits for it,
        forwarding its progress), or None (no child, or it failed)."""
        return self.job.result(progress, rerun=False)

    def close(self) -> None:
        """Stop the child if it still runs (an error or Ctrl-C in the parent)."""
        self.job.close()


def cmd_buffer_test(args) -> int:
    from vectoradjust.accuracy.buffer import buffer_test

    widths = parse_widths(args.widths)
    tested, crs = read_lines(args.tested, layer=args.tested_layer)
    reference, _ = read_lines(args.reference, crs, layer=args.reference_layer)
    rows = buffer_test(tested, reference, widths,
                       method="exact" if getattr(args, "exact", False) else "polygon")
    print(f"vectoradjust buffer-test: {args.tested} inside buffers of {args.reference}")
    print("   width m   share %   inside m    total m")
    for r in rows:
        share = "-" if r["share"] is None else f"{100 * r['share']:8.2f}"
        print(f"  {r['width']:8.2f}  {share:>8s}  {r['length_inside']:9.1f}  "
              f"{r['length_total']:9.1f}")
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        with open(out, "w", newline="", encoding="utf-8") as fh:
            w = csv.DictWriter(fh, fieldnames=["width", "share", "length_inside",
                                               "length_total"])
            w.writeheader()
            w.writerows(rows)
        print(f"  wrote {out}")
    return 0


def add_parser(sub, common=None) -> None:
    """Register ``vectoradjust buffer-test``."""
    b = sub.add_parser("buffer-test", help="share of a line layer's length inside buffers of a "
                       "reference line layer (Goodchild & Hunter)")
    b.add_argument("tested", help="the line layer under test (e.g. OSM roads)")
    b.add_argument("reference", help="the reference line layer (e.g. surveyed centrelines)")
    b.add_argument("--widths", default="1,2,5", help="buffer widths in metres (default 1,2,5)")
    b.add_argument("--tested-layer", help="layer of a multi-layer source (e.g. features)")
    b.add_argument("--reference-layer", help="layer of a multi-layer reference source")
    b.add_argument("-o", "--out", help="write the table to this CSV file")
    b.add_argument("--exact", action="store_true",
                   help="exact round buffers by segments (linear time, for large layers; "
                        "the default polygon buffers are up to 0.03 %% of the width narrower "
                        "on round caps and joins)")
    b.set_defaults(func=cmd_buffer_test)

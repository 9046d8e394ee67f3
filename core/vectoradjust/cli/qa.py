"""``vectoradjust qa``: accuracy control of a project's adjustment (``docs/method.md`` section 7).

``vectoradjust qa PROJECT.toml --out DIR [--product P] [--scale M] [--contour-interval H]
[--terrain T] [--pixel-size MM] [--free-model | --no-free-model]`` adjusts the project,
judges every stage against the tolerances of the product specification (``[qa]`` in the
project; the options override it), writes ``DIR/qa.json`` and prints the verdict, the
non-conformities with the point ids to re-measure (or the zones short of tie points), a
table of the stages and the production checks (tie-point zones, inter-strip ties, free
model). ``[[images]] strip`` labels, when given, define the strips.

The console script registers the subcommand with :func:`add_parser`; ``python -m
vectoradjust.cli.qa`` runs it alone.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Optional

from vectoradjust.cli import options
from vectoradjust.cli.tools import run_alone, write_json
from vectoradjust.errors import VectorAdjustError
from vectoradjust.qa.free_model import FREE_MODEL_MAX_IMAGES
from vectoradjust.qa.text import format_report

__all__ = ["add_parser", "cmd_qa", "format_report", "write_qa_json", "main"]



def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``vectoradjust qa`` to ``subparsers``; its parser (``func``: :func:`cmd_qa`)."""
    q = options.add_project_command(
        subparsers, "qa", cmd_qa,
        "accuracy control: judge the adjustment against production tolerances",
        "adjust the project and judge every stage (interior and relative orientation, "
        "triplets, tie-point zones, inter-strip ties, the free model, control and check "
        "points) against the tolerances that follow from the product specification ([qa] in "
        "the project; the options below override it); write qa.json",
        out_help="output directory (qa.json is written there)")
    q.add_argument("--product", help='"topographic map" (or topographic-map), "orthophoto" or '
                                     '"orthomosaic"')
    q.add_argument("--scale", help="scale denominator of the product, e.g. 2000 or 1:2000")
    options.add_contour_interval(q, help="contour interval of the map in m")
    q.add_argument("--terrain", help="flat, hilly or mountainous (orthomosaic tolerances)")
    q.add_argument("--pixel-size", type=float, metavar="MM",
                   help="scanning / sensor pixel size in mm, e.g. 0.012 (default: [qa] "
                        "pixel_size or the camera's)")
    q.add_argument("--pairs", choices=("consecutive", "all"), default="consecutive",
                   help="stereo pairs: consecutive images of [[images]] or every pair with "
                        "common points")
    q.add_argument("--point-rule", choices=("limit", "mean"), default="limit",
                   help="a control/check point fails over twice the mean tolerance (limit) "
                        "or over the mean tolerance itself (mean)")
    q.add_argument("--free-model", action=argparse.BooleanOptionalAction, default=None,
                   help="adjust the free model (image measurements only, inner constraints) "
                        "as a QA stage: its sigma0 and image residuals before control "
                        f"(default: on for frame blocks of at most {FREE_MODEL_MAX_IMAGES} "
                        "images: it is a second bundle adjustment)")
    options.add_vectors(q)
    options.add_quiet(q)
    return q


def write_qa_json(report: dict, out_dir, extra: Optional[dict] = None) -> Path:
    """Write ``qa.json`` (verdict and non-conformities first) into ``out_dir``.

    Parameters
    ----------
    report : dict
        ``QAReport.as_dict()``.
    out_dir : str or os.PathLike
        Created if missing.
    extra : dict, optional
        Keys appended (e.g. ``project``).

    Returns
    -------
    pathlib.Path
    """
    doc = dict(report)
    if extra:
        doc.update(extra)
    return write_json(out_dir, "qa.json", doc)


def cmd_qa(args) -> int:
    """Run ``vectoradjust qa`` (see :func:`add_parser` for the arguments).

    Returns
    -------
    int
        0 when the accuracy control ran (whatever the verdict; it is in ``qa.json``).
    """
    from vectoradjust.cli.progress import ProgressBar
    from vectoradjust.files.project import load_project
    from vectoradjust.files.readers import load_project_data
    from vectoradjust.pipeline import run
    from vectoradjust.qa.verdict import accuracy_control, spec_from_table, strips_from_project

    project = load_project(args.project)
    # the specification is checked before the (possibly long) adjustment
    spec = spec_from_table(project.raw.get("qa"), product=args.product, scale=args.scale,
                           contour_interval=args.contour_interval, terrain=args.terrain,
                           source=str(args.project))
    if args.pixel_size is not None and not args.pixel_size > 0:
        raise VectorAdjustError(f"--pixel-size {args.pixel_size} is not a pixel size",
                                "Give the pixel size in millimetres, e.g. --pixel-size 0.012")
    bar = ProgressBar("qa", enabled=not args.quiet)
    bar(0.0, "reading inputs")
    data = load_project_data(project)
    result = run(data, vectors=args.vectors, progress=bar)
    report = accuracy_control(result, spec, pixel_size=args.pixel_size, pairs=args.pairs,
                              point_rule=args.point_rule, strips=strips_from_project(project.raw),
                              free_model=args.free_model)
    doc = report.as_dict()
    path = write_qa_json(doc, args.out, extra={"project": str(args.project)})
    from vectoradjust.files.report import write_report

    html = write_report(result, Path(args.out) / "report.html", qa=doc,
                        reliability=result.reliability)
    print(f"vectoradjust qa: {args.project}")
    print(format_report(doc))
    print(f"  wrote {path} and {html}")
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Run the ``qa`` subcommand alone: ``python -m vectoradjust.cli.qa PROJECT --out DIR``."""
    return run_alone(add_parser, "qa", argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""Stage results and the verdict: :class:`StageResult`, :func:`check_stage`, parallax
stages, :class:`QAVerdict` and :func:`qa_verdict`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from vectoradjust.qa.tolerances.limits import _pixel, max_from_mean, relative_orientation_tolerance
from vectoradjust.qa.tolerances.product import STATISTICS

__all__ = ["StageResult", "QAVerdict", "check_stage", "parallax_stages", "qa_verdict"]


def _json_number(x):
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


@dataclass
class StageResult:
    """The outcome of one accuracy-control stage.

    Attributes
    ----------
    name : str
        Stage name, e.g. ``"block: GCP XY"``.
    tolerance : float
        Tolerance of the stage statistic.
    measured : float
        The statistic (NaN when there were no values).
    statistic : str
        ``"mean"``, ``"rms"`` or ``"max"`` (of the absolute values).
    point_tolerance : float
        Limit for a single point.
    passed : bool or None
        ``None`` when nothing was measured (not evaluated).
    unit : str
    rows : list of dict
        Per point ``{id, value, tolerance, passed}``.
    warnings : list
        Ids of rows that pass with a warning (a tie-point zone with 2 points).
    action : str
        What a failed row asks for: ``"re-measure"`` (its ids are points, listed in
        ``remeasure``) or e.g. ``"add tie points"`` (its ids are zones).
    """

    name: str
    tolerance: float
    measured: float
    statistic: str
    point_tolerance: float
    passed: bool | None
    unit: str = ""
    rows: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    action: str = "re-measure"

    @property
    def status(self) -> str:
        """``"pass"``, ``"fail"`` or ``"n/a"``."""
        return "n/a" if self.passed is None else ("pass" if self.passed else "fail")

    @property
    def failed_ids(self) -> list:
        """Ids of the points over their limit (to re-measure)."""
        return [r["id"] for r in self.rows if r["passed"] is False]

    def as_dict(self) -> dict:
        """JSON-serialisable copy."""
        return {
            "name": self.name,
            "status": self.status,
            "passed": self.passed,
            "statistic": self.statistic,
            "measured": _json_number(self.measured),
            "tolerance": _json_number(self.tolerance),
            "point_tolerance": _json_number(self.point_tolerance),
            "unit": self.unit,
            "failed_ids": list(self.failed_ids),
            "warnings": list(self.warnings),
            "action": self.action,
            "points": [
                {"id": r["id"], "value": _json_number(r["value"]),
                 "tolerance": _json_number(r["tolerance"]), "passed": r["passed"]}
                for r in self.rows
            ],
        }


def check_stage(name: str, values, ids: Sequence | None, tolerance: float,
                statistic: str = "mean", *, point_tolerance: float | None = None,
                unit: str = "") -> StageResult:
    """Judge one stage: its statistic against the tolerance, every point against its limit.

    Parameters
    ----------
    name : str
        Stage name for the report.
    values : array_like, shape (k,)
        Per-point errors; absolute values are used, NaNs ignored (reported as not
        evaluated).
    ids : sequence or None
        Point ids (``None``: ``0..k-1``).
    tolerance : float
        Tolerance of the statistic.
    statistic : {"mean", "rms", "max"}
        Statistic of ``|values|`` compared with ``tolerance``.
    point_tolerance : float, optional
        Limit for a single point. Default: ``2 tolerance`` for a mean
        (``E_max ~ 2 E_mean``), ``sqrt(2) tolerance`` for an RMS (``2 RMS / sqrt 2``),
        ``tolerance`` for a max.
    unit : str
        Unit label of values and tolerances.

    Returns
    -------
    StageResult
        ``passed`` is True when the statistic is within the tolerance AND no point is
        over its limit; ``None`` when there are no finite values.
    """
    if statistic not in STATISTICS:
        raise ValueError(f"statistic must be one of {STATISTICS}, got {statistic!r}")
    v = np.abs(np.asarray(values, float).ravel())
    ids = list(range(v.size)) if ids is None else list(ids)
    if len(ids) != v.size:
        raise ValueError(f"{len(ids)} ids for {v.size} values")
    tol = float(tolerance)
    if point_tolerance is None:
        point_tolerance = {"mean": max_from_mean(tol), "rms": math.sqrt(2.0) * tol,
                           "max": tol}[statistic]
    ptol = float(point_tolerance)
    finite = np.isfinite(v)
    if not finite.any():
        measured = float("nan")
    elif statistic == "mean":
        measured = float(v[finite].mean())
    elif statistic == "rms":
        measured = float(np.sqrt(np.mean(v[finite] ** 2)))
    else:
        measured = float(v[finite].max())
    ok = v <= ptol
    rows = [
        {"id": i, "value": float(x), "tolerance": ptol, "passed": (bool(o) if f else None)}
        for i, x, o, f in zip(ids, v.tolist(), ok.tolist(), finite.tolist())
    ]
    if not finite.any():
        passed: bool | None = None
    else:
        passed = bool(measured <= tol) and bool(ok[finite].all())
    return StageResult(name=name, tolerance=tol, measured=measured, statistic=statistic,
                       point_tolerance=ptol, passed=passed, unit=unit, rows=rows)


def parallax_stages(name: str, py_mm, ids: Sequence | None, pixel_size_mm: float) -> list:
    """Relative-orientation stages of one stereo pair: mean |py| <= 0.5 px, max <= 1 px.

    Parameters
    ----------
    name : str
        Pair name, e.g. ``"L-R"``.
    py_mm : array_like, shape (k,)
        Vertical parallaxes (mm).
    ids : sequence or None
        Point ids.
    pixel_size_mm : float

    Returns
    -------
    list of StageResult
        ``relative orientation <name>: mean |py|`` and ``...: max |py|``, in pixels;
        every point is judged against 1 pixel in both.
    """
    p = _pixel(pixel_size_mm)
    tol = relative_orientation_tolerance(p)
    py_px = np.asarray(py_mm, float) / p
    return [
        check_stage(f"relative orientation {name}: mean |py|", py_px, ids, tol.mean_px,
                    "mean", point_tolerance=tol.max_px, unit="px"),
        check_stage(f"relative orientation {name}: max |py|", py_px, ids, tol.max_px,
                    "max", unit="px"),
    ]


@dataclass
class QAVerdict:
    """Overall verdict: every evaluated stage passed. Failing stages come first."""

    passed: bool
    stages: list
    nonconformities: list

    @property
    def remeasure(self) -> list:
        """Ids of all points to re-measure, worst stage first, each once."""
        seen: dict = {}
        for n in self.nonconformities:
            if n.get("action", "re-measure") != "re-measure":
                continue  # zone names, not points
            for i in n["ids"]:
                seen.setdefault(i, None)
        return list(seen)

    def as_dict(self) -> dict:
        """JSON-serialisable copy: verdict, non-conformities first, then all stages."""
        return {
            "verdict": "pass" if self.passed else "fail",
            "passed": self.passed,
            "nonconformities": [dict(n) for n in self.nonconformities],
            "remeasure": self.remeasure,
            "stages": [s.as_dict() for s in self.stages],
        }


def qa_verdict(stages: Sequence[StageResult]) -> QAVerdict:
    """Combine stage results into a verdict with the non-conformities first.

    Parameters
    ----------
    stages : sequence of StageResult

    Returns
    -------
    QAVerdict
        ``passed`` is True when no evaluated stage failed (stages with nothing to
        measure do not fail the block). ``stages`` is reordered: failed, then passed,
        then not evaluated (stable within each group). ``nonconformities`` lists, per
        failed stage, the statistic, its tolerance and the point ids to re-measure
        (worst first).
    """
    order = {"fail": 0, "pass": 1, "n/a": 2}
    ordered = sorted(stages, key=lambda s: order[s.status])
    nonconf = []
    for s in ordered:
        if s.status != "fail":
            continue
        bad = [r for r in s.rows if r["passed"] is False]
        sign = 1.0 if s.statistic == "min" else -1.0  # counts: the fewest first
        bad.sort(key=lambda r: sign * r["value"])
        nonconf.append({
            "stage": s.name,
            "statistic": s.statistic,
            "measured": _json_number(s.measured),
            "tolerance": _json_number(s.tolerance),
            "point_tolerance": _json_number(s.point_tolerance),
            "unit": s.unit,
            "action": s.action,
            "ids": [r["id"] for r in bad],
        })
    passed = not any(s.status == "fail" for s in ordered)
    return QAVerdict(passed=passed, stages=ordered, nonconformities=nonconf)


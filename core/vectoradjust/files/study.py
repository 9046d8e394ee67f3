"""The dissertation's experiments on in-memory project data (``vectoradjust study``).

- :func:`gcp_study` - the same project adjusted with fewer ground control points: a
  number sweep (24/12/6/3, well spread), named configurations ("3-North", "3-East",
  "3-SW": the points of one part of the block) or random subsets with repetitions; the
  control points held out become check points (intersected from the adjusted
  orientation, not in the adjustment) and are scored as such (Table 17, Fig 5.11,
  Tables 18-21, Fig 5.12).
- :func:`shift_study` - a database translated by given offsets, adjusted, and compared
  with the unshifted run (Tables 13-16).
- :func:`identification_study` - the simulator re-run with a list of identification
  errors (``pointing_sigma``).

Each run is :func:`vectoradjust.pipeline.run` on a modified copy of the
:class:`~vectoradjust.model.ProjectData` (no temporary project files). Progress is
``progress(fraction, message)`` over all runs; ``is_cancelled`` is polled by every run
(:class:`vectoradjust.errors.CancelledError`). Tables are written with :mod:`csv`;
figures and ``report.html`` by :mod:`vectoradjust.files.study_report`.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from vectoradjust.accuracy.study import (
    directional_subset,
    parse_configuration,
    random_subsets,
    recovered_shift,
    spread_stats,
    spread_subset,
)
from vectoradjust.accuracy.tables import one_vertex_per_point, truth_points
from vectoradjust.errors import CancelledError, ProjectError, VectorAdjustError
from vectoradjust.model import ProjectData

__all__ = ["gcp_plan", "with_control", "gcp_study", "gcp_summary", "shift_data",
           "shift_study", "identification_study", "write_csv", "truth_point_rows",
           "truth_point_columns", "rows_from_columns",
           "default_numbers", "common_points"]

Progress = Optional[Callable[[float, str], None]]


def _say(progress: Progress, fraction: float, message: str) -> None:
    if progress is not None:
        progress(min(max(fraction, 0.0), 1.0), message)


def _check(is_cancelled) -> None:
    if is_cancelled is not None and is_cancelled():
        raise CancelledError("The study was cancelled", "Run it again to completion")


def _sub(progress: Progress, i: int, n: int, label: str) -> Progress:
    """The progress of run ``i`` of ``n`` as a part of the study's."""
    if progress is None:
        return None
    return lambda f, msg="": progress((i + min(max(f, 0.0), 1.0)) / n, f"{label}: {msg}")


# --------------------------------------------------------------------------- GCP study
def _control_rows(data: ProjectData) -> np.ndarray:
    """Rows of the control file with role control (the candidates of a GCP study)."""
    rows = np.flatnonzero(data.control.role == "control")
    if len(rows) < 3:
        raise ProjectError(f"{data.control.source}: a GCP study needs at least 3 control "
                           f"points (role control), there are {len(rows)}",
                           "Add control points to the control file")
    return rows


def default_numbers(n: int) -> list:
    """The number sweep of a project with ``n`` control points: n, n/2, n/4, ... down to 3
    (24, 12, 6, 3 for the dissertation's 24)."""
    out = [int(n)]
    while out[-1] // 2 >= 3:
        out.append(out[-1] // 2)
    if out[-1] > 3:
        out.append(3)
    return out


def _named(data: ProjectData, rows: np.ndarray, name: str) -> np.ndarray:
    """The control rows of a configuration: ``"3-North"`` or ``"NAME=ID1,ID2,..."``."""
    ctrl = data.control
    if "=" in name:
        label, _, ids = name.partition("=")
        want = [i.strip() for i in ids.split(",") if i.strip()]
        pos = {str(p): int(r) for r, p in zip(rows, ctrl.point_id[rows])}
        bad = [i for i in want if i not in pos]
        if bad:
            raise ProjectError(f"configuration {label!r}: {', '.join(bad)} are not control "
                               f"points of {ctrl.source}",
                               "Name control points (role control) of the control file")
        return np.array([pos[i] for i in want], np.int64)
    parsed = parse_configuration(name)
    if parsed is None:
        raise ProjectError(f"GCP configuration {name!r} is not known",
                           "Write COUNT-PART (e.g. 3-North, 3-East, 3-SW, 4-Center, "
                           "6-Spread) or NAME=ID1,ID2,ID3")
    k, part = parsed
    return rows[directional_subset(ctrl.xyz[rows, :2], k, part)]


def gcp_plan(data: ProjectData, numbers: Optional[Sequence[int]] = None,
             configurations: Sequence[str] = (), random_numbers: Sequence[int] = (),
             repeats: int = 10, seed: int = 0) -> list:
    """The runs of a GCP study: which control points each keeps.

    Parameters
    ----------
    data : ProjectData
    numbers : sequence of int, optional
        Number sweep with well-spread subsets (:func:`default_numbers` when None and
        neither ``configurations`` nor ``random_numbers`` are given; ``[]`` for none).
    configurations : sequence of str
        Named configurations: ``COUNT-PART`` (``3-North``, ``3-East``, ``3-SW``,
        ``4-Center``, ``6-Spread``) or ``NAME=ID1,ID2,...``.
    random_numbers : sequence of int
        Numbers of control points drawn at random, ``repeats`` times each.
    repeats, seed : int

    Returns
    -------
    list of dict
        ``label``, ``group`` (``number``, ``configuration`` or ``random``), ``n``,
        ``repeat`` and ``rows`` (control-file rows kept as control).
    """
    rows = _control_rows(data)
    xy = data.control.xyz[rows, :2]
    if numbers is None and not configurations and not random_numbers:
        numbers = default_numbers(len(rows))
    plan = []
    for k in numbers or []:
        if not 3 <= int(k) <= len(rows):
            raise ProjectError(f"{k} control points: the project has {len(rows)} (at least "
                               "3 are needed)", f"Give numbers from 3 to {len(rows)}")
        plan.append({"label": f"{int(k)} spread", "group": "number", "n": int(k),
                     "repeat": 0, "rows": rows[spread_subset(xy, int(k))]})
    for name in configurations:
        sel = _named(data, rows, name)
        plan.append({"label": name.partition("=")[0], "group": "configuration",
                     "n": len(sel), "repeat": 0, "rows": sel})
    for k in random_numbers:
        for r, sub in enumerate(random_subsets(len(rows), int(k), repeats, seed)):
            plan.append({"label": f"{int(k)} random", "group": "random", "n": int(len(sub)),
                         "repeat": r + 1, "rows": rows[sub]})
    return plan


def with_control(data: ProjectData, keep_rows: np.ndarray) -> ProjectData:
    """A copy of ``data`` whose control points other than ``keep_rows`` are check points."""
    role = data.control.role.copy()
    held = np.flatnonzero(role == "control")
    held = held[~np.isin(held, keep_rows)]
    role[held] = "check"
    return replace(data, control=replace(data.control, role=role))


def _database_scores(run) -> dict:
    """Per database: residual RMSE, truth comparison (points counted once)."""
    out = {}
    for e in run.summary["databases"]:
        t = e.get("truth") or {}
        out[e["name"]] = {"rmse": e["residuals"].get("rmse_horizontal"),
                          "true_rmse": t.get("rmse_database_truth_horizontal"),
                          "adjusted_truth_rmse": t.get("rmse_adjusted_truth_horizontal"),
                          "moved_closer": t.get("moved_closer")}
    return out


def _gcp_row(item: dict, data: ProjectData, run) -> dict:
    """One row of the GCP study table."""
    cp = run.control_points
    held = np.zeros(len(cp["point_id"]), bool)
    held[np.flatnonzero(data.control.role == "control")] = True
    held[item["rows"]] = False
    used = held & (cp["Used"] == 1)
    dh = np.hypot(cp["Vx"][used], cp["Vy"][used])
    chk = run.summary["check_points"]
    row = {"label": item["label"], "group": item["group"], "n_control": item["n"],
           "repeat": item["repeat"],
           "control_ids": " ".join(map(str, data.control.point_id[item["rows"]])),
           "n_check": chk.get("count"), "check_rmse_x": chk.get("rmse_x"),
           "check_rmse_y": chk.get("rmse_y"), "check_rmse_z": chk.get("rmse_z"),
           "check_rmse_h": chk.get("rmse_horizontal"), "n_held_out": int(used.sum()),
           "held_out_rmse_h": float(np.sqrt(np.mean(dh ** 2))) if dh.size else None,
           "sigma0_squared": run.summary.get("sigma0_squared"), "error": ""}
    for name, s in _database_scores(run).items():
        row[f"{name}_rmse"] = s["rmse"]
        row[f"{name}_adj_truth"] = s["adjusted_truth_rmse"]
    return row


def gcp_study(data: ProjectData, plan: list, *, vectors: Optional[list] = None,
              progress: Progress = None, is_cancelled=None) -> list:
    """Adjust ``data`` once per entry of ``plan`` (:func:`gcp_plan`) and score each run.

    Returns
    -------
    list of dict
        One row per run: the kept control ids, the check point RMSE (held-out and the
        project's own check points together: ``check_rmse_*``; held-out only:
        ``held_out_rmse_h``), sigma0^2 and per database the residual RMSE
        (``<db>_rmse``) and, with truth, the adjusted - truth RMSE (``<db>_adj_truth``).
        A run that cannot be adjusted (e.g. collinear control) has its reason in
        ``error``.

    Notes
    -----
    The runs are made without the conflation of the unmeasured vertices: no score of
    the table depends on it (they are those of the control, check and measured shape
    points), and its covariance fit is the larger part of a run on a small project
    (issue 32).
    """
    from vectoradjust.pipeline import run as adjust

    rows = []
    unconflated = replace(data, conflation={**(data.conflation or {}), "enabled": False})
    for i, item in enumerate(plan):
        _check(is_cancelled)
        _say(progress, i / len(plan), f"GCP study: {item['label']} ({i + 1}/{len(plan)})")
        sub = with_control(unconflated, item["rows"])
        try:
            res = adjust(sub, vectors=vectors, is_cancelled=is_cancelled,
                         progress=_sub(progress, i, len(plan), item["label"]))
        except CancelledError:
            raise
        except VectorAdjustError as exc:
            rows.append({"label": item["label"], "group": item["group"],
                         "n_control": item["n"], "repeat": item["repeat"],
                         "control_ids": " ".join(map(str, data.control.point_id[item["rows"]])),
                         "error": str(exc)})
            continue
        rows.append(_gcp_row(item, data, res))
    _say(progress, 1.0, "GCP study: done")
    return rows


def gcp_summary(rows: list) -> list:
    """Mean, sd, min and max of the RMSE columns per label (repeated random subsets).

    Returns
    -------
    list of dict
        ``label, group, n_control, runs`` and ``<column>_mean/_sd/_min/_max`` for the
        check, held-out and per-database RMSE columns.
    """
    keys = [k for r in rows for k in r if k.endswith(("_rmse_h", "_rmse", "_adj_truth"))]
    keys = list(dict.fromkeys(keys))
    out = []
    for label in dict.fromkeys(r["label"] for r in rows):
        grp = [r for r in rows if r["label"] == label]
        entry = {"label": label, "group": grp[0]["group"], "n_control": grp[0]["n_control"],
                 "runs": len(grp), "failed": sum(1 for r in grp if r.get("error"))}
        for k in keys:
            s = spread_stats([r.get(k) for r in grp])
            for stat in ("mean", "sd", "min", "max"):
                entry[f"{k}_{stat}"] = s[stat]
        out.append(entry)
    return out


# --------------------------------------------------------------------------- shift study
def shift_data(data: ProjectData, dx: float, dy: float, names: Sequence[str]) -> ProjectData:
    """A copy of ``data`` whose databases ``names`` are translated by ``(dx, dy)`` (m).

    Z stays as read (the DEM is not sampled again at the shifted XY); the image
    measurements and the truth stay as they are.
    """
    known = [spec.name for spec, _ in data.vectors]
    bad = [n for n in names if n not in known]
    if bad:
        raise ProjectError(f"{data.source}: no [[vectors]] entry named {', '.join(bad)}",
                           f"Use one of: {', '.join(known)}")
    t = np.array([float(dx), float(dy), 0.0])
    vectors = [(spec, replace(layer, coords=layer.coords + t) if spec.name in names else layer)
               for spec, layer in data.vectors]
    return replace(data, vectors=vectors)


def _shift_row(name: str, dx: float, dy: float, base, shifted) -> dict:
    """Unshifted against shifted run of one database."""
    d0 = next(d for d in base.databases if d.name == name)
    d1 = next(d for d in shifted.databases if d.name == name)
    e0 = next(e for e in base.summary["databases"] if e["name"] == name)
    e1 = next(e for e in shifted.summary["databases"] if e["name"] == name)
    one = one_vertex_per_point(d0.vertex_point)
    v = [np.column_stack([d.vertices[c] for c in ("Vx", "Vy", "Vz")])[one] for d in (d0, d1)]
    rec = recovered_shift(v[0], v[1])
    moved = np.hypot(*(d1.adjusted_coords[one, :2] - d0.adjusted_coords[one, :2]).T)
    t0, t1 = e0.get("truth") or {}, e1.get("truth") or {}
    off = (e1.get("offset") or {}).get("values") or [None, None]
    row = {"database": name, "dx": dx, "dy": dy, "points": int(one.sum()),
           "rmse_unshifted": e0["residuals"]["rmse_horizontal"],
           "rmse_shifted": e1["residuals"]["rmse_horizontal"],
           "true_rmse_unshifted": t0.get("rmse_database_truth_horizontal"),
           "true_rmse_shifted": t1.get("rmse_database_truth_horizontal"),
           "recovery_shifted": t1.get("recovery_rate"),
           "adj_truth_unshifted": t0.get("rmse_adjusted_truth_horizontal"),
           "adj_truth_shifted": t1.get("rmse_adjusted_truth_horizontal"),
           "closer_shifted": t1.get("moved_closer"),
           "recovered_dx": rec["dx"], "recovered_dy": rec["dy"],
           "recovered_sd_x": rec["sd_x"], "recovered_sd_y": rec["sd_y"],
           "adjusted_moved_max": float(moved.max()) if moved.size else None,
           "offset_dx": off[0], "offset_dy": off[1]}
    for which, entry in (("unshifted", t0), ("shifted", t1)):
        buf = entry.get("buffer") or {}
        for w, b, a in zip(buf.get("widths", []), buf.get("before", []), buf.get("after", [])):
            row[f"in_{w:g}m_before_{which}"] = b
            row[f"in_{w:g}m_after_{which}"] = a
    return row


def shift_study(data: ProjectData, dx: float, dy: float, names: Optional[Sequence[str]] = None,
                *, progress: Progress = None, is_cancelled=None, after_run=None):
    """Adjust each database as read and translated by ``(dx, dy)``, and compare.

    Parameters
    ----------
    data : ProjectData
    dx, dy : float
        The translation (m): east and north.
    names : sequence of str, optional
        Databases to shift (default: all); each is adjusted alone.
    after_run : callable, optional
        ``after_run(run, label)`` after each adjustment (e.g. the buffer test against
        ``[truth]`` centrelines).

    Returns
    -------
    rows : list of dict
        Per database: residual and true RMSE unshifted/shifted, recovery, the recovered
        shift (``recovered_dx/dy``: mean of V_unshifted - V_shifted), how far the
        adjusted points moved between the runs, the estimated database offset.
    runs : list of (AdjustmentRun, AdjustmentRun)
        Unshifted and shifted run per database.
    """
    from vectoradjust.pipeline import run as adjust

    names = list(names) if names else [spec.name for spec, _ in data.vectors]
    moved = shift_data(data, dx, dy, names)
    rows, runs = [], []
    n = 2 * len(names)
    for i, name in enumerate(names):
        pair = []
        for j, (label, d) in enumerate((("unshifted", data), ("shifted", moved))):
            _check(is_cancelled)
            res = adjust(d, vectors=[name], is_cancelled=is_cancelled,
                         progress=_sub(progress, 2 * i + j, n, f"{name} {label}"))
            if after_run is not None:
                after_run(res, f"{name} {label}")
            pair.append(res)
        rows.append(_shift_row(name, float(dx), float(dy), *pair))
        runs.append(tuple(pair))
    _say(progress, 1.0, "shift study: done")
    return rows, runs


# --------------------------------------------------------------------------- identification
def identification_study(errors: Sequence[float], *, seed: int = 35, repeats: int = 1,
                         databases: Sequence[str] = ("OSM", "TNM", "TIGER"),
                         reweight: str = "two-pass", state_sigma: bool = True,
                         progress: Progress = None, is_cancelled=None) -> list:
    """Re-run the simulator with each identification error and adjust.

    Parameters
    ----------
    errors : sequence of float
        Horizontal identification errors (``pointing_sigma``, m per axis).
    seed : int
        Seed of the first scenario; repeat ``r`` uses ``seed + r``.
    repeats : int
    databases : sequence of str
        Simulated databases (adjusted together).
    reweight : str
        ``[adjustment] reweight`` of the runs.
    state_sigma : bool
        Give each database ``identification_sigma = (error, 0)`` (else none: each run
        estimates it from the data or uses the default, :func:`vectoradjust.pipeline.run`).

    Returns
    -------
    list of dict
        Per error, repeat and database: residual RMSE, database - truth and adjusted -
        truth RMSE, recovery, improvement, share within CE90, moved closer, and the
        identification error estimated from the data (when the run gives one). The runs
        are made without the conflation of the unmeasured vertices, which none of these
        depends on (issue 32).
    """
    from vectoradjust.pipeline import run as adjust
    from vectoradjust.simulate import make_scenario

    rows = []
    jobs = [(float(e), r) for e in errors for r in range(int(repeats))]
    for i, (err, r) in enumerate(jobs):
        _check(is_cancelled)
        _say(progress, i / len(jobs), f"identification {err:g} m, seed {seed + r}")
        sc = make_scenario(seed=seed + r, databases=tuple(databases), pointing_sigma=err)
        data = sc.to_project_data()
        data.settings = replace(data.settings, reweight=reweight)
        data.vectors = [(replace(spec, identification_sigma=(err, 0.0) if state_sigma
                                 else None), layer) for spec, layer in data.vectors]
        # no score of the table depends on the unmeasured vertices: no conflation
        data = replace(data, conflation={**(data.conflation or {}), "enabled": False})
        res = adjust(data, is_cancelled=is_cancelled,
                     progress=_sub(progress, i, len(jobs), f"identification {err:g} m"))
        for e in res.summary["databases"]:
            t = e.get("truth") or {}
            est = (res.summary.get("identification_estimates") or {}).get(
                "databases", {}).get(e["name"]) or {}
            rows.append({"identification_error": err, "seed": seed + r, "database": e["name"],
                         "points": e.get("points"),
                         "rmse": e["residuals"].get("rmse_horizontal"),
                         "true_rmse": t.get("rmse_database_truth_horizontal"),
                         "recovery": t.get("recovery_rate"),
                         "adj_truth_rmse": t.get("rmse_adjusted_truth_horizontal"),
                         "improvement": t.get("improvement"),
                         "within_ce90": t.get("share_within_ce90"),
                         "moved_closer": t.get("moved_closer"),
                         "estimated_identification": est.get("horizontal")})
    _say(progress, 1.0, "identification study: done")
    return rows


# --------------------------------------------------------------------------- tables
def truth_point_columns(run) -> Optional[dict]:
    """The per-point truth table of every database of a run, as columns.

    Returns
    -------
    dict of str to numpy.ndarray or None
        ``database`` followed by the columns of
        :func:`vectoradjust.accuracy.tables.truth_points`, all databases one after the
        other; None when no database has vertex truth.
    """
    parts = []
    for d in run.databases:
        cols = truth_points(run, d)
        if cols is not None:
            n = len(cols["point_id"])
            parts.append({"database": np.full(n, d.name, dtype=object), **cols})
    if not parts:
        return None
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def rows_from_columns(cols: Optional[dict]) -> list:
    """Columns (equal-length arrays) as a list of dict rows of Python scalars."""
    if not cols:
        return []
    lists = {k: np.asarray(v).tolist() for k, v in cols.items()}
    return [dict(zip(lists, vals)) for vals in zip(*lists.values())]


def truth_point_rows(run) -> list:
    """The per-point truth table of every database of a run (one dict per point)."""
    return rows_from_columns(truth_point_columns(run))


#: rows formatted at once by the column writer
_CSV_CHUNK = 65536


def _cell(x) -> str:
    """One CSV cell: empty for None/NaN, the shortest round-trip text of a float; text
    holding a comma, quote or line break is quoted as :mod:`csv` does."""
    if x is None or (isinstance(x, float) and x != x):
        return ""
    t = repr(x) if isinstance(x, float) else str(x)
    if "," in t or '"' in t or "\n" in t or "\r" in t:
        return '"' + t.replace('"', '""') + '"'
    return t


def _column_text(values) -> list:
    """The CSV cells of one column (floats and integers without per-cell checks)."""
    a = np.asarray(values)
    if a.dtype.kind == "f":  # 15 significant digits (DBL_DIG): 3x faster than repr
        return ["" if x != x else "%.15g" % x for x in a.tolist()]  # noqa: UP031 (fastest)
    if a.dtype.kind in "iub":
        return [str(x) for x in a.tolist()]
    return [_cell(x) for x in a.tolist()]


def _arrow_array(values):
    """One column as a pyarrow array whose CSV text is that of :func:`_column_text`
    (NaN and None as nulls: empty cells), or None when pyarrow cannot take it as is."""
    import pyarrow as pa

    a = np.asarray(values)
    if a.dtype.kind == "f":
        return pa.array(a, mask=np.isnan(a))
    if a.dtype.kind in "iu":
        return pa.array(a)
    if a.dtype.kind == "U":  # numpy text
        return pa.array(a.tolist(), type=pa.string())
    if a.dtype.kind == "b":  # as the plain writer: True / False
        return pa.array(np.where(a, "True", "False").tolist(), type=pa.string())
    if a.dtype.kind != "O":  # bytes and the like: the plain writer
        return None
    try:
        arr = pa.array(a, from_pandas=True)  # None and NaN are nulls
    except (pa.ArrowInvalid, pa.ArrowTypeError, OverflowError):
        return None  # mixed kinds (text and numbers): the plain writer
    ok = pa.types.is_string(arr.type) or pa.types.is_floating(arr.type) or \
        pa.types.is_integer(arr.type) or pa.types.is_null(arr.type)
    return arr if ok else None


def _arrow_csv(columns: dict, path: Path, progress) -> bool:
    """Write a column table with pyarrow's CSV writer (C++, about 3x faster than Python
    formatting); False (nothing written) when pyarrow is missing or a column is of a
    kind it would write differently (e.g. booleans as ``true``).

    The cells are those of the plain writer, except floats: the shortest text that reads
    back as the same double (up to 17 significant digits) instead of 15 digits. Text is
    quoted only in a file where some cell needs it (then every text cell is).
    """
    try:
        import pyarrow as pa
        import pyarrow.compute as pc
        import pyarrow.csv as pcsv
    except ImportError:
        return False
    arrays = [_arrow_array(c) for c in columns.values()]
    if any(a is None for a in arrays):
        return False
    special = any(pc.any(pc.match_substring_regex(a, '[,"\r\n]')).as_py()
                  for a in arrays if pa.types.is_string(a.type))
    table = pa.table(arrays, names=[str(k) for k in columns])
    try:
        options = pcsv.WriteOptions(include_header=False, eol="\r\n",
                                    quoting_style="needed" if special else "none")
    except TypeError:  # an older pyarrow without eol / quoting_style
        return False
    n = table.num_rows
    with open(path, "w", newline="", encoding="utf-8") as fh:
        csv.writer(fh).writerow(list(columns))
    with open(path, "ab") as fh, pcsv.CSVWriter(fh, table.schema, write_options=options) as w:
        for i in range(0, max(n, 1), _CSV_CHUNK):
            w.write_table(table.slice(i, _CSV_CHUNK))
            if progress is not None:
                progress(min(1.0, (i + _CSV_CHUNK) / max(n, 1)))
    return True


def write_csv(rows, path, progress: Optional[Callable[[float], None]] = None) -> Path:
    """Write a table as CSV: a list of dict rows (the union of their keys as columns) or
    a dict of equal-length column arrays (written by pyarrow's CSV writer when it is
    installed: floats as the shortest text that reads back as the same number; else
    formatted column by column in chunks of rows, floats with 15 significant digits).
    None and NaN are written as empty cells; ``progress(fraction)`` after each chunk of
    a column table."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(rows, dict) and _arrow_csv(rows, path, progress):
        return path
    if isinstance(rows, dict):  # columns: formatted a chunk of rows at a time
        cols = [np.asarray(c) for c in rows.values()]
        n = len(cols[0]) if cols else 0
        with open(path, "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(list(rows))
            for i in range(0, n, _CSV_CHUNK):  # bounded memory: no string per cell held
                text = [_column_text(c[i:i + _CSV_CHUNK]) for c in cols]
                fh.write("".join(",".join(r) + "\r\n" for r in zip(*text)))
                if progress is not None:
                    progress(min(1.0, (i + _CSV_CHUNK) / n))
        return path
    cols = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=cols)
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in cols})
    return path


def _measured_points(run) -> dict:
    """Measured id -> (database, vertex id, X, Y, AdjX, AdjY) of a run's shape points."""
    obs_p = run.problem.obs_point
    shape = run.point_kind[obs_p] == "shape"
    ids = run.data.measurements.point_id[run.obs_rows[shape]]
    pts = obs_p[shape]
    out = {}
    for d in run.databases:
        one = one_vertex_per_point(d.vertex_point)
        first = np.full(run.problem.n_points, -1, np.int64)
        first[d.vertex_point[one]] = np.flatnonzero(one)
        v = first[pts]
        for mid, i in zip(ids[v >= 0], v[v >= 0]):
            xyz, adj = d.shape.layer.coords[i], d.adjusted_coords[i]
            out.setdefault(str(mid), {})[d.name] = (str(d.shape.vertex_ids[i]), *xyz[:2],
                                                    *adj[:2])
    return out


def common_points(runs: Sequence) -> list:
    """The common-point comparison of databases adjusted alone (``compare``).

    A measured point is common when the runs of two or more databases used it: a
    database's own vertex and, with ``[adjustment] reuse_tolerance``, the coinciding
    vertex of another database that reused its measurements. One row per measured point:
    per database its vertex id, database XY, residual (Vx, Vy) and adjusted XY, and
    ``adjusted_spread`` (largest horizontal distance between the databases' adjusted
    positions: what the exterior orientation of the separate runs changes).
    """
    merged: dict = {}
    for run in runs:
        for mid, per_db in _measured_points(run).items():
            merged.setdefault(mid, {}).update(per_db)
    rows = []
    for mid, per_db in merged.items():
        if len(per_db) < 2:
            continue
        row = {"measured_id": mid}
        adj = []
        for name, (vid, x, y, ax, ay) in per_db.items():
            row.update({f"{name}_id": vid, f"{name}_X": x, f"{name}_Y": y,
                        f"{name}_Vx": ax - x, f"{name}_Vy": ay - y, f"{name}_AdjX": ax,
                        f"{name}_AdjY": ay})
            adj.append((ax, ay))
        a = np.asarray(adj)
        row["adjusted_spread"] = float(np.max(np.hypot(*(a[:, None] - a[None]).T)))
        rows.append(row)
    return rows

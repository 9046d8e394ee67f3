"""The QA report as text: verdict, non-conformities and the stage tables."""

from __future__ import annotations

from vectoradjust.formatting import fmt_number

__all__ = ["format_report", "production_lines"]

_MAX_IDS = 20  # failing point ids printed per stage (all are in qa.json)


def _f(v, nd: int = 3) -> str:
    return fmt_number(v, nd)


def _table(heads: list, rows: list, indent: str = "  ") -> list:
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h)
              for i, h in enumerate(heads)]
    lines = [indent + "  ".join(h.ljust(w) if i == 0 else h.rjust(w)
                                for i, (h, w) in enumerate(zip(heads, widths)))]
    for r in rows:
        lines.append(indent + "  ".join(c.ljust(w) if i == 0 else c.rjust(w)
                                        for i, (c, w) in enumerate(zip(r, widths))))
    return lines


def format_report(report: dict) -> str:
    """A readable text rendering of a QA report (``QAReport.as_dict()``).

    Verdict first, then the non-conformities with the ids to re-measure, the stage
    table, the vertical parallax per stereo pair, the triplets, the control points, the
    DTM heights at them and the notes.
    """
    spec = report["specification"]
    lines = []
    if spec["product"] == "topographic map":
        what = (f"topographic map 1:{_f(spec['map_scale'], 0)}, contour interval "
                f"{_f(spec['contour_interval'], 2)} m")
    else:
        scale = spec.get("orthophoto_scale") or spec.get("map_scale")
        what = f"{spec['product']} 1:{_f(scale, 0)}, terrain {spec['terrain']}"
    px = report.get("pixel_size_mm")
    pxt = (f"pixel size {_f(px, 4)} mm ({report.get('pixel_size_source')})" if px
           else "pixel size unknown")
    lines.append(f"  product: {what}; {pxt}")
    n_nc = len(report["nonconformities"])
    n_na = len(report["not_evaluated"])
    verdict = "PASS" if report["passed"] else "FAIL"
    tail = []
    if n_nc:
        tail.append(f"{n_nc} non-conformit{'y' if n_nc == 1 else 'ies'}")
    if n_na:
        tail.append(f"{n_na} stage(s) not evaluated")
    lines.append(f"  VERDICT: {verdict}" + (f" ({'; '.join(tail)})" if tail else ""))
    if n_nc:
        lines.append("  Non-conformities (re-measure these points):")
        for n in report["nonconformities"]:
            ids = n["ids"]
            shown = ", ".join(str(i) for i in ids[:_MAX_IDS])
            if len(ids) > _MAX_IDS:
                shown += f", ... ({len(ids) - _MAX_IDS} more in qa.json)"
            action = n.get("action", "re-measure")
            what = ("point(s) over the limit" if action == "re-measure"
                    else f"under the limit ({action})")
            lines.append(f"    {n['stage']}: {n['statistic']} {_f(n['measured'])} {n['unit']} "
                         f"(tolerance {_f(n['tolerance'])}, point limit "
                         f"{_f(n['point_tolerance'])}); "
                         f"{len(ids)} {what}" + (f": {shown}" if ids else ""))
    lines.append("  Stages:")
    rows = [[s["name"], s["statistic"], _f(s["measured"]), _f(s["tolerance"]),
             _f(s["point_tolerance"]), s["unit"], str(len(s["points"])),
             "WARN" if s["status"] == "pass" and s.get("warnings") else s["status"].upper()]
            for s in report["stages"]]
    lines += _table(["stage", "stat", "measured", "tolerance", "pt limit", "unit", "n",
                     "status"], rows, "    ")
    if report["stereo_pairs"]:
        lines.append("  Vertical parallax after the adjustment (|py|):")
        rows = [[f"{p['left']}-{p['right']}", str(p["n"]), _f(p["mean_um"], 2), _f(p["rms_um"], 2),
                 _f(p["max_um"], 2), _f(p["mean_px"], 2), _f(p["rms_px"], 2), _f(p["max_px"], 2)]
                for p in report["stereo_pairs"]]
        lines += _table(["pair", "n", "mean um", "rms um", "max um", "mean px", "rms px",
                         "max px"], rows, "    ")
    if report["triplets"]:
        lines.append("  Triplets (discrepancies between adjacent models, image scale):")
        rows = [["-".join(t["images"]), str(t["n"]), _f(t["base_mm"], 1),
                 _f(t["mean_e_xy_um"], 2), _f(t.get("tolerance_e_xy_um"), 2),
                 _f(t["mean_e_z_um"], 2), _f(t.get("tolerance_e_z_um"), 2)]
                for t in report["triplets"]]
        lines += _table(["triplet", "n", "b mm", "E_xy um", "tol", "E_z um", "tol"], rows,
                        "    ")
    if report["control_points"]:
        lines.append("  Control and check points (m):")
        rows = [[c["id"], c["role"], _f(c["e_xy"]), _f(c["tolerance_xy"]), _f(c["e_z"]),
                 _f(c["tolerance_z"]), c["qa"].upper()] for c in report["control_points"]]
        lines += _table(["point", "role", "e_xy", "limit", "e_z", "limit", "QA"], rows, "    ")
    if report.get("dtm_points"):
        lines.append("  DTM heights at control and check points (m, DEM minus surveyed):")
        rows = [[d["id"], d["role"], _f(d["z"]), _f(d["z_dem"]), _f(d["dz"]),
                 _f(d.get("tolerance")), str(d.get("qa", "n/a")).upper()]
                for d in report["dtm_points"]]
        lines += _table(["point", "role", "Z", "Z DEM", "dz", "limit", "QA"], rows, "    ")
    lines += production_lines(report)
    for n in report["notes"]:
        lines.append(f"  note: {n}")
    return "\n".join(lines)


def _zone_table(title: str, entries: list) -> list:
    """Per overlap one row: counted points per zone (top row first) and the status."""
    if not entries:
        return []
    names = [z["zone"] for z in entries[0]["zones"]]
    lines = [f"  {title}:"]
    rows = []
    for e in entries:
        counts = {z["zone"]: z for z in e["zones"]}
        rows.append(["-".join(e["images"]), str(e["points"])]
                    + [f"{counts[n]['count']}" + ("" if counts[n]["status"] == "pass" else
                                                  f" {counts[n]['status']}")
                       if n in counts else "-" for n in names]
                    + [str(sum(z["road"] for z in e["zones"])), e["status"].upper()])
    return lines + _table(["overlap", "points", *names, "road", "status"], rows, "    ")


def production_lines(report: dict) -> list:
    """Text lines of the production checks: tie-point zones, inter-strip ties, free model.

    Parameters
    ----------
    report : dict
        ``QAReport.as_dict()`` (keys ``tie_zones``, ``triplet_zones``, ``strips``,
        ``inter_strip``, ``free_model``; absent keys are skipped).

    Returns
    -------
    list of str
    """
    lines = _zone_table("Tie-point zones per stereo pair (counted points per zone; road "
                        "vertices separately)", report.get("tie_zones") or [])
    lines += _zone_table("Triplet zones (points on three consecutive images, triple overlap)",
                         report.get("triplet_zones") or [])
    strips = report.get("strips") or {}
    if strips.get("strips"):
        lines.append(f"  Strips ({strips.get('source')}): "
                     + "; ".join(f"{s['strip']}: {', '.join(s['images'])}"
                                 for s in strips["strips"]))
    inter = report.get("inter_strip") or []
    if inter:
        lines.append("  Inter-strip ties (points measured in both strips, vertical parallax):")
        rows = [[f"{t['strips'][0]}-{t['strips'][1]}", str(t["n_points"]), str(t["n_counted"]),
                 str(t["min_per_image"]), str(t["ray_pairs"]),
                 _f(t["parallax"].get("mean_px"), 2), _f(t["parallax"].get("max_px"), 2),
                 _f(t["parallax"].get("mean_um"), 2)] for t in inter]
        lines += _table(["strips", "points", "counted", "min/image", "rays", "mean px",
                         "max px", "mean um"], rows, "    ")
    fm = report.get("free_model") or {}
    if fm.get("sigma0") is not None:
        lines.append(f"  Free model (image measurements only, inner constraints): sigma0 "
                     f"{_f(fm['sigma0'])} (limit {_f(fm.get('sigma0_bound'))}, r = {fm['dof']}),"
                     f" residual RMS x {_f(fm.get('rms_x_um'), 2)} um, y "
                     f"{_f(fm.get('rms_y_um'), 2)} um, pooled {_f(fm.get('rms_px'), 2)} px")
    return lines

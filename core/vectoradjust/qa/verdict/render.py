"""The verdict rendered: its HTML section and the flat production rows.
"""

from __future__ import annotations

import html

from vectoradjust.formatting import fmt_number

__all__ = ["html_section", "production_rows"]


def html_section(report: dict) -> str:
    """An HTML fragment (``<section>``) of a QA report for ``report.html``.

    Parameters
    ----------
    report : dict
        :meth:`QAReport.as_dict`.

    Returns
    -------
    str
    """
    e = html.escape
    spec = report["specification"]
    verdict = report["verdict"].upper()
    if spec["product"] == "topographic map":
        scale = spec.get("map_scale")
    else:
        scale = spec.get("orthophoto_scale") or spec.get("map_scale")
    head = f"product {spec['product']}, scale 1:{fmt_number(scale, 0)}"
    if spec.get("contour_interval"):
        head += f", contour interval {fmt_number(spec['contour_interval'], 2)} m"
    head += f", pixel size {fmt_number(report.get('pixel_size_mm'), 4)} mm"
    out = ['<section id="accuracy-control">', "<h2>Accuracy control</h2>",
           f"<p><strong>Verdict: {e(verdict)}</strong> &mdash; {e(head)}</p>"]
    if report["nonconformities"]:
        out.append("<h3>Non-conformities</h3><ul>")
        for n in report["nonconformities"]:
            ids = ", ".join(e(str(i)) for i in n["ids"]) or "(the statistic)"
            out.append(f"<li>{e(n['stage'])}: {e(n['statistic'])} {fmt_number(n['measured'])} "
                       f"{e(n['unit'])} &gt; {fmt_number(n['tolerance'])}; re-measure: {ids}</li>")
        out.append("</ul>")
    out.append("<table><thead><tr><th>stage</th><th>statistic</th><th>measured</th>"
               "<th>tolerance</th><th>point limit</th><th>unit</th><th>status</th>"
               "</tr></thead><tbody>")
    for s in report["stages"]:
        out.append(f"<tr><td>{e(s['name'])}</td><td>{e(s['statistic'])}</td>"
                   f"<td>{fmt_number(s['measured'])}</td><td>{fmt_number(s['tolerance'])}</td>"
                   f"<td>{fmt_number(s['point_tolerance'])}</td><td>{e(s['unit'])}</td>"
                   f"<td>{e(s['status'])}</td></tr>")
    out.append("</tbody></table>")
    for title, rows in production_rows(report):
        out.append(f"<h3>{e(title)}</h3><table><thead><tr>"
                   + "".join(f"<th>{e(k)}</th>" for k in rows[0]) + "</tr></thead><tbody>")
        out += ["<tr>" + "".join(f"<td>{e(str(v))}</td>" for v in r.values()) + "</tr>"
                for r in rows]
        out.append("</tbody></table>")
    if report["notes"]:
        out.append("<ul>" + "".join(f"<li>{e(n)}</li>" for n in report["notes"]) + "</ul>")
    out.append("</section>")
    return "\n".join(out)


def _zone_rows_flat(entries: list) -> list:
    rows = []
    for t in entries:
        row = {"overlap": "-".join(t["images"]), "points": t["points"]}
        for z in t["zones"]:
            row[z["zone"]] = f"{z['count']} ({z['status']})"
        row["road vertices"] = sum(z["road"] for z in t["zones"])
        row["status"] = t["status"]
        rows.append(row)
    return rows


def production_rows(report: dict) -> list:
    """The production checks as flat tables for HTML: ``[(title, rows), ...]``.

    Parameters
    ----------
    report : dict
        :meth:`QAReport.as_dict` (missing keys are skipped).

    Returns
    -------
    list of (str, list of dict)
        Tie-point zones per stereo pair, triplet zones, inter-strip ties, free model;
        only the non-empty ones.
    """
    out = []
    for key, title in (("tie_zones", "Tie-point zones per stereo pair (counted points)"),
                       ("triplet_zones", "Triplet zones (triple overlap)")):
        rows = _zone_rows_flat(report.get(key) or [])
        if rows:
            out.append((title, rows))
    inter = [{"strips": "-".join(t["strips"]), "points": t["n_points"],
              "counted": t["n_counted"], "min per image": t["min_per_image"],
              "ray pairs": t["ray_pairs"], "mean |py| px": fmt_number(
                  t["parallax"].get("mean_px"), 2),
              "max |py| px": fmt_number(t["parallax"].get("max_px"), 2)}
             for t in report.get("inter_strip") or []]
    if inter:
        out.append(("Inter-strip ties", inter))
    fm = report.get("free_model") or {}
    if fm.get("sigma0") is not None:
        out.append(("Free model (before control)", [{
            "sigma0": fmt_number(fm["sigma0"], 3), "limit": fmt_number(fm["sigma0_bound"], 3),
            "dof": fm["dof"], "RMS x um": fmt_number(fm["rms_x_um"], 2),
            "RMS y um": fmt_number(fm["rms_y_um"], 2),
            "RMS px": fmt_number(fm.get("rms_px"), 2)}]))
    return out


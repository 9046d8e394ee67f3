"""The buffer test (Goodchild & Hunter 1997) on the command line and against truth lines.

``vectoradjust buffer-test TESTED REFERENCE --widths 1,2,5`` prints the share of the
tested lines' length inside buffers of the reference lines, measured in the tested
layer's CRS (the reference is transformed to it). A tested layer in a geographic CRS
(degrees) or in a projected one not in metres is measured in the UTM zone of its
centre, and the output says so; ``--crs`` chooses the projected CRS. With a ``[truth]`` table
(true centrelines) in the project, ``adjust`` and ``compare`` add the share of each
database's lines inside 1 m and 2 m (or ``widths``) of the truth before and after the
adjustment to ``summary.json`` (``databases[].truth.buffer``), measured with the exact
round buffers (``buffer-test --exact``), linear in the size of the data.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

from vectoradjust.cli import options
from vectoradjust.files.truth import parse_widths, project_truth, read_lines, truth_buffer
from vectoradjust.runner.alongside import TruthBeforeAlongside

__all__ = ["add_parser", "cmd_buffer_test", "read_lines", "truth_buffer", "parse_widths",
           "project_truth", "TruthBeforeAlongside", "measuring_crs", "utm_crs"]


def utm_crs(lon: float, lat: float):
    """The WGS 84 UTM zone of a place (UPS north of 84 N and south of 80 S), a pyproj CRS.

    Parameters
    ----------
    lon, lat : float
        Degrees.
    """
    from pyproj import CRS

    if lat > 84.0:
        return CRS.from_epsg(32661)
    if lat < -80.0:
        return CRS.from_epsg(32761)
    zone = int(((lon + 180.0) % 360.0) // 6.0) + 1
    return CRS.from_epsg((32600 if lat >= 0.0 else 32700) + zone)


def _in_metres(crs) -> bool:
    unit = crs.axis_info[0].unit_name if crs.axis_info else "metre"
    return unit in ("metre", "meter", "m")


def _parses(crs) -> bool:
    """``crs`` is a CRS pyproj understands and is projected in metres."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError as _PCRSError

    try:
        c = CRS.from_user_input(crs)
    except _PCRSError:
        return False
    return c.is_projected and _in_metres(c)


def measuring_crs(path, layer=None, crs=None) -> tuple:
    """The projected CRS (metres) a buffer test of the layer at ``path`` measures in.

    Parameters
    ----------
    path : str or os.PathLike
        The tested layer.
    layer : str, optional
        Its layer in a multi-layer source.
    crs : str, optional
        Given by the user (``--crs``): checked to be projected, in metres.

    Returns
    -------
    crs : pyproj.CRS or None
        None: the layer's own CRS (projected, in metres; or unreadable, which
        :func:`read_lines` then names).
    note : str or None
        What the output says when the CRS is not the layer's own.

    Raises
    ------
    CRSError
        ``crs`` is not a projected CRS in metres, or the layer is in degrees and has
        no extent to place a UTM zone.
    """
    from vectoradjust.errors import CRSError
    from vectoradjust.files.readers import check_projected_crs

    if crs:
        given = check_projected_crs(crs, "--crs") if _parses(crs) else None
        if given is None or not (given.is_projected and _in_metres(given)):
            raise CRSError(f"--crs {crs!r} is not a projected CRS in metres",
                           "Give a projected CRS in metres, e.g. the data's UTM zone "
                           "(--crs EPSG:326xx north, EPSG:327xx south)")
        return given, None
    import pyogrio
    from pyproj import CRS, Transformer

    try:
        info = pyogrio.read_info(path, layer=layer, force_total_bounds=True)
        own = CRS.from_user_input(info["crs"]) if info.get("crs") else None
    except Exception:  # noqa: BLE001 - read_lines says what is wrong with the file
        return None, None
    if own is None or (own.is_projected and _in_metres(own)) or \
            not (own.is_geographic or own.is_projected):
        return None, None
    b = info.get("total_bounds")
    if b is None or not all(abs(float(v)) < 1e300 for v in b):
        raise CRSError(f"{path}: the layer is in {own.name!r} (not metres) and has no "
                       "features to place a UTM zone by",
                       "Give --crs with a projected CRS in metres (e.g. --crs EPSG:32633)")
    to_lonlat = Transformer.from_crs(own, "EPSG:4326", always_xy=True)
    lon, lat = to_lonlat.transform((b[0] + b[2]) / 2.0, (b[1] + b[3]) / 2.0)
    utm = utm_crs(lon, lat)
    what = "a geographic CRS" if own.is_geographic else "a projected CRS not in metres"
    note = (f"{path} is in {what} ({own.name}): the buffers are measured in {utm.name} "
            f"(EPSG:{utm.to_epsg()}), the UTM zone of the data's centre ({lon:.4f}, "
            f"{lat:.4f}); give --crs to measure in another projected CRS")
    west, _ = to_lonlat.transform(b[0], (b[1] + b[3]) / 2.0)
    east, _ = to_lonlat.transform(b[2], (b[1] + b[3]) / 2.0)
    if abs(east - west) > 6.0:
        note += (f". The data span {abs(east - west):.1f} degrees of longitude, more than "
                 "a zone: lengths far from its centre are stretched (give --crs)")
    return utm, note


def cmd_buffer_test(args) -> int:
    from vectoradjust.accuracy.buffer import buffer_test

    widths = parse_widths(args.widths)
    work, note = measuring_crs(args.tested, args.tested_layer, getattr(args, "crs", None))
    tested, crs = read_lines(args.tested, work, layer=args.tested_layer)
    reference, _ = read_lines(args.reference, crs, layer=args.reference_layer)
    rows = buffer_test(tested, reference, widths,
                       method="exact" if getattr(args, "exact", False) else "polygon")
    print(f"vectoradjust buffer-test: {args.tested} inside buffers of {args.reference}")
    if note:
        print(f"  note: {note}")
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


def add_parser(sub) -> argparse.ArgumentParser:
    """Register ``vectoradjust buffer-test``; its parser."""
    b = options.add_command(sub, "buffer-test", cmd_buffer_test,
                            "share of a line layer's length inside buffers of a reference "
                            "line layer (Goodchild & Hunter)")
    b.add_argument("tested", help="the line layer under test (e.g. OSM roads)")
    b.add_argument("reference", help="the reference line layer (e.g. surveyed centrelines)")
    b.add_argument("--widths", default="1,2,5", help="buffer widths in metres")
    b.add_argument("--tested-layer", help="layer of a multi-layer source (e.g. features)")
    b.add_argument("--reference-layer", help="layer of a multi-layer reference source")
    options.add_out(b, required=False, help="write the table to this CSV file")
    options.add_crs(b, help="projected CRS in metres to measure in (e.g. EPSG:32633) "
                            "(default: the tested layer's, or the UTM zone of its centre "
                            "when it is in degrees)")
    b.add_argument("--exact", action="store_true",
                   help="exact round buffers by segments (linear time, for large layers; "
                        "the default polygon buffers are up to 0.03 %% of the width narrower "
                        "on round caps and joins)")
    return b

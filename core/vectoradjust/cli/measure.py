"""``vectoradjust measure``: predicted positions, chips, transfer and road junctions.

``vectoradjust measure predict PROJECT.toml --out DIR [--image ID=FILE] [--orientation
summary.json] [--chips png|tif|none] [--roads]`` writes ``DIR/measurement_template.csv``
(every control, check and shape point on every image it falls on: pixel and mm position
and search ellipse), a chip per point and image (``DIR/chips/<image>/<point>.png``)
and, with ``--roads``, the junction and corner shape points located automatically
(``DIR/automatic_points.csv``, all attempts with their flags).

``vectoradjust measure transfer PROJECT.toml --measured FILE --out DIR [--automatic
DIR/automatic_points.csv] [--max-anisotropy 5] [--back-tolerance 0.5]`` finds every
point measured on one image (``FILE``:
``point_id,image_id,col,row`` in pixels, e.g. the filled-in template) on the other
images, writes every attempt with its quality to ``DIR/transfer.csv`` and the accepted
measurements to ``DIR/image_points.csv`` in the contract format (photo mm) - ready for
``vectoradjust adjust`` - and, row for row, with their source (manual, transferred,
automatic), correlation coefficient, LSM sigma and pixel position to
``DIR/image_points_quality.csv`` (the contract reader refuses extra columns). Every
field of :class:`vectoradjust.measure.transfer.MatchSettings` is a flag of ``transfer``
(:func:`add_settings_flags`: name, type, default and help from the dataclass), and the
values used go to ``DIR/transfer_settings.json``.

Images are named by ``path`` in each ``[[images]]`` entry or by ``--image ID=FILE``; an
RPC image (``model = "rpc"``) without ``path`` is read from its ``rpc`` file when that is
an image (not an ``_rpc.txt`` / ``.RPB`` side file). RPC images' pixels are GDAL's
(``0, 0`` at the upper-left corner of the first pixel) in every table; their search
windows hold the bias of ``--orientation`` (a previous adjustment's estimate) or, before
one, the project's ``bias_sigma`` (else the RPC's ``ERR_BIAS``, else 10 px shift and 2 px
drift a priori), and the transfer's terrain height error along the reference image's
line of sight (``--sigma-height``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Optional

import numpy as np

from vectoradjust.cli import options
from vectoradjust.errors import ProjectError

__all__ = ["add_parser", "cmd_predict", "cmd_transfer", "CONTRACT_COLUMNS", "SETTINGS_FLAGS",
           "add_settings_flags", "settings_from_args", "settings_help"]

#: the columns of image_points.csv that ``adjust`` reads (docs/method.md section 9); the quality
#: columns (source, ncc, lsm_sigma, col, row) go to image_points_quality.csv
CONTRACT_COLUMNS = ("point_id", "image_id", "x", "y", "sigma_x", "sigma_y")


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``measure predict`` and ``measure transfer`` to the ``vectoradjust`` sub-parsers."""
    m = subparsers.add_parser("measure", help="measure on the images: predict, transfer",
                              description="predicted image positions, chips and automatic "
                                          "measurement (transfer by NCC + least-squares "
                                          "matching; road junctions) towards image_points.csv")
    sub = m.add_subparsers(dest="measure_command", required=True)
    p = sub.add_parser("predict", help="predicted positions, search windows, chips",
                       description="predicted positions, search windows and chips of every "
                                   "control, check and shape point on every image",
                       formatter_class=options.HelpFormatter)
    _common(p)
    p.add_argument("--chips", choices=("png", "tif", "none"), default="png",
                   help="chip format per point and image")
    p.add_argument("--chip-size", type=int, default=64, help="chip half size (pixels)")
    p.add_argument("--roads", action="store_true",
                   help="also locate junction and corner shape points automatically")
    p.add_argument("--road-width", type=float, default=6.0, help="road surface width (m)")
    p.set_defaults(func=cmd_predict)
    t = sub.add_parser("transfer", help="find measured points on the other images",
                       description="find points measured on one image on the other images "
                                   "(NCC over a pyramid, least-squares matching, back-matching)",
                       formatter_class=options.HelpFormatter)
    _common(t)
    t.add_argument("--measured", required=True,
                   help="CSV point_id,image_id,col,row of points measured (pixels)")
    t.add_argument("--automatic", help="automatic_points.csv of predict --roads to include")
    add_settings_flags(t)
    t.add_argument("--sigma-height", type=float, default=2.0,
                   help="uncertainty of the terrain height (m) for the search window")
    t.set_defaults(func=cmd_transfer)
    return m


#: MatchSettings fields whose flag is not ``--field-name``
SETTINGS_FLAGS = {"k": "--window-k"}


def settings_help(cls=None) -> dict:
    """``{field: text}``: the description of each attribute in the numpydoc ``Attributes``
    section of a settings dataclass (default :class:`MatchSettings`), reST markup removed.

    The flags' help (:func:`add_settings_flags`) comes from here, so the docstring is
    the one definition (README's option table is checked against the parser by
    ``tests/test_measure_sample.py``); an attribute the docstring documents together
    with another one (``a, b : float``) gets that text under both names.
    """
    import inspect
    import re

    from vectoradjust.measure.transfer import MatchSettings

    doc = inspect.getdoc(cls or MatchSettings) or ""
    body = doc.split("Attributes\n----------\n", 1)[-1]
    out: dict = {}
    names: list = []
    for line in body.splitlines():
        head = re.match(r"^([A-Za-z_][\w, ]*) : ", line)
        if head:
            names = [n.strip() for n in head.group(1).split(",")]
            for n in names:
                out[n] = ""
        elif line.startswith("    ") and names:
            for n in names:
                out[n] = (out[n] + " " + line.strip()).strip()
    for n, text in out.items():
        text = re.sub(r"\s*\(:\w+:`[^`]*`\)", "", text)  # a bare cross-reference
        text = re.sub(r":\w+:`~?(?:[\w.]*\.)?(\w+)`", r"\1", text)
        out[n] = _help_style(text.replace("``", ""))
    return out


def _help_style(text: str) -> str:
    """A docstring's description in the command line's help style (cli/options.py):
    lower-case start (not an acronym such as NCC), no final period."""
    first = text.split(" ", 1)[0]
    if first[:1].isupper() and first[1:2].islower():
        text = text[0].lower() + text[1:]
    return text[:-1] if text.endswith(".") and not text.endswith("...") else text


def add_settings_flags(p: argparse.ArgumentParser, cls=None) -> None:
    """One flag per field of a settings dataclass (default :class:`MatchSettings`), in the
    order of its fields: ``--field-name`` (:data:`SETTINGS_FLAGS` for the exceptions), the
    field's type and default, its docstring's description as help; a ``bool`` field gets
    ``--name`` / ``--no-name``. Read back with :func:`settings_from_args`."""
    import dataclasses

    from vectoradjust.measure.transfer import MatchSettings

    cls = cls or MatchSettings
    helps = settings_help(cls)
    g = p.add_argument_group("matching thresholds (MatchSettings)")
    for f in dataclasses.fields(cls):
        flag = SETTINGS_FLAGS.get(f.name, "--" + f.name.replace("_", "-"))
        text = helps.get(f.name, "").replace("%", "%%")  # HelpFormatter: the default
        if f.type in ("bool", bool):
            g.add_argument(flag, dest=f.name, default=f.default, help=text,
                           action=argparse.BooleanOptionalAction)
        else:
            kind = {"int": int, "float": float, "str": str}.get(str(f.type), f.type)
            if not callable(kind):
                raise TypeError(f"{cls.__name__}.{f.name}: no flag for type {f.type!r}")
            g.add_argument(flag, dest=f.name, type=kind, default=f.default, help=text,
                           metavar="N" if kind is int else "X")


def settings_from_args(args, cls=None):
    """The settings dataclass (default :class:`MatchSettings`) of the parsed flags of
    :func:`add_settings_flags`."""
    import dataclasses

    from vectoradjust.measure.transfer import MatchSettings

    cls = cls or MatchSettings
    return cls(**{f.name: getattr(args, f.name) for f in dataclasses.fields(cls)})


def _common(p) -> None:
    options.add_project(p)
    options.add_out(p)
    p.add_argument("--image", action="append", metavar="ID=FILE",
                   help="image file of an [[images]] id (overrides its path; repeat for "
                        "more images)")
    p.add_argument("--orientation", help="summary.json of an adjustment: use its adjusted "
                                         "orientation and sigmas")
    options.add_quiet(p)


def _image_paths(spec, overrides: list) -> dict:
    paths = {}
    for entry in spec.raw.get("images", []):
        if isinstance(entry, dict) and entry.get("path"):
            q = Path(str(entry["path"]))
            paths[str(entry["id"])] = str(q if q.is_absolute() else spec.base_dir / q)
    for im in spec.images:  # an RPC image's rpc file may be the image itself
        if im.id not in paths and im.model == "rpc" and im.rpc.path and \
                Path(im.rpc.path).suffix.lower() not in (".txt", ".rpb"):
            paths[im.id] = str(im.rpc.path)
    for o in overrides or ():
        if "=" not in o:
            raise ProjectError(f"--image {o!r} is not ID=FILE", "Write e.g. --image L=left.tif")
        k, v = o.split("=", 1)
        if k not in {im.id for im in spec.images}:
            raise ProjectError(f"--image {o!r}: no [[images]] entry has id {k!r}",
                               f"Use one of {', '.join(im.id for im in spec.images)}")
        paths[k] = v
    missing = [im.id for im in spec.images if im.id not in paths]
    if missing:
        raise ProjectError(f"no image file for {', '.join(missing)}",
                           'Add path = "image.tif" to each [[images]] entry or give '
                           "--image ID=FILE")
    return paths


def _load(args):
    """Project, geometries, readers, points and height function."""
    from vectoradjust.adjust.dem import bilinear
    from vectoradjust.files.csv_tables import read_control
    from vectoradjust.files.images import RasterioImage
    from vectoradjust.files.measuring import image_geometries, project_points
    from vectoradjust.files.project import load_project
    from vectoradjust.files.readers import (
        _parts,
        check_projected_crs,
        control_to_project_crs,
        read_dem,
        read_line_layer,
        sample_dem,
    )

    spec = load_project(args.project)
    where = str(spec.path)
    crs = check_projected_crs(spec.crs, f"{where}: crs")
    orientation = None
    if args.orientation:
        orientation = json.loads(Path(args.orientation).read_text(encoding="utf-8"))
    readers = {k: RasterioImage(v, k) for k, v in _image_paths(spec, args.image).items()}
    control = read_control(spec.control["path"]) if spec.control is not None else None
    if control is not None:
        control = control_to_project_crs(control, spec, crs, where)
    fid_path = spec.measurements.get("fiducials")
    fiducials = None
    if fid_path and spec.measurements.get("unit", "mm") == "pixel":
        from vectoradjust.files.csv_tables import read_fiducials

        fiducials = read_fiducials(fid_path, "pixel")
    geoms = image_geometries(spec, orientation,
                             image_sizes={k: r.size for k, r in readers.items()},
                             control=control, fiducials=fiducials,
                             ground_frame=_ground_frame(spec, crs))
    layers, height = [], None
    for v in spec.vectors:
        layer = read_line_layer(v.path, v.name, v.id_field, _parts(crs)[0], v.layer, v.where)
        if v.dem:
            layer.coords[:, 2] = sample_dem(v.dem, layer.coords[:, :2], _parts(crs)[0])
            if height is None:
                grid, gt, nodata, _ = read_dem(v.dem)
                height = _dem_height(bilinear, grid, gt, nodata)
        layers.append((v, layer))
    points = project_points(control, layers, spec.settings.merge_tolerance)
    if height is None:
        from vectoradjust.files.measure_rows import control_height

        height = control_height(control)
    return spec, geoms, readers, points, height


def _ground_frame(spec, crs):
    """Read the RPCs of the project's RPC images; the ground frame (None without them)."""
    if not spec.has_rpc:
        return None
    from types import SimpleNamespace

    from vectoradjust.files.readers import read_rpc_images

    holder = SimpleNamespace(images=spec.images, ground_frame=None)
    read_rpc_images(holder, spec, crs.to_string())
    return holder.ground_frame


def _say_rpc(geoms: dict) -> None:
    """One line per RPC image: where its bias and search window come from."""
    from vectoradjust.files.measure_rows import rpc_bias_line
    from vectoradjust.measure.geometry import RpcGeometry

    for iid, g in geoms.items():
        if isinstance(g, RpcGeometry):
            print("  " + rpc_bias_line(iid, g, digits=".3g"))


def _dem_height(bilinear, grid, gt, nodata):
    """The terrain height from the DEM; the DEM's mean height where it has none."""
    from vectoradjust.files.measure_rows import height_from_samples

    fallback = float(np.nanmean(np.where(grid == nodata, np.nan, grid))) if nodata is not None \
        else float(np.nanmean(grid))
    return height_from_samples(lambda xy: bilinear(grid, gt, xy, nodata=nodata), fallback)


def cmd_predict(args) -> int:
    """Run ``vectoradjust measure predict``."""
    from vectoradjust.cli.progress import ProgressBar
    from vectoradjust.files.images import write_table
    from vectoradjust.files.measuring import measure_roads, predict

    bar = ProgressBar("measure", enabled=not args.quiet)
    spec, geoms, readers, points, _ = _load(args)
    out = Path(args.out)
    tab = predict(geoms, points, progress=lambda f, m: bar(0.3 * f, m))
    path = write_table(out / "measurement_template.csv", tab)
    if args.chips != "none":
        _write_chips(out / "chips", tab, readers, args.chip_size, args.chips,
                     lambda f, m: bar(0.3 + 0.4 * f, m),
                     {k: g.index_offset for k, g in geoms.items()})
    print(f"vectoradjust measure predict: {len(tab['point_id'])} predictions on "
          f"{len(geoms)} images -> {path}")
    _say_rpc(geoms)
    if args.roads:
        auto = measure_roads(geoms, readers, points, args.road_width,
                             progress=lambda f, m: bar(0.7 + 0.3 * f, m))
        apath = write_table(out / "automatic_points.csv", auto)
        print(f"  road junctions/corners: {int(auto['accepted'].sum())} of "
              f"{len(auto['accepted'])} located -> {apath}")
    bar(1.0, "done")
    return 0


def _write_chips(folder: Path, tab: dict, readers: dict, half: int, fmt: str, progress,
                 offsets: Optional[dict] = None) -> None:
    """A chip per row of ``tab``, centred on the array element of its pixel (``offsets``:
    per image, the pixel coordinate of element 0's centre, 0.5 for GDAL's pixels)."""
    from vectoradjust.files.images import write_chip

    n = len(tab["point_id"])
    for i in range(n):  # I/O: one file per point and image
        iid, pid = str(tab["image_id"][i]), str(tab["point_id"][i])
        o = (offsets or {}).get(iid, 0.0)
        col, row = (tab["col"][i] - o, tab["row"][i] - o) if o else (tab["col"][i],
                                                                     tab["row"][i])
        c0, r0 = int(round(col)) - half, int(round(row)) - half
        chip = readers[iid].read(c0, r0, 2 * half + 1, 2 * half + 1)
        mark = (col - c0, row - r0)
        write_chip(folder / iid / f"{_safe(pid)}.{fmt}", chip, c0, r0, mark)
        if progress is not None and i % 50 == 0:
            progress(i / max(n, 1), "writing chips")


def _safe(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name)


def cmd_transfer(args) -> int:
    """Run ``vectoradjust measure transfer``."""
    from vectoradjust.cli.progress import ProgressBar
    from vectoradjust.files.images import read_pixel_table, write_table
    from vectoradjust.files.measuring import image_points, transfer

    bar = ProgressBar("measure", enabled=not args.quiet)
    spec, geoms, readers, points, height = _load(args)
    measured = read_pixel_table(args.measured)
    st = settings_from_args(args)
    res = transfer(geoms, readers, measured, height, st, sigma_height=args.sigma_height,
                   progress=bar)
    out = Path(args.out)
    write_table(out / "transfer.csv", res)
    _write_settings(out / "transfer_settings.json", st, args.sigma_height)
    auto = _read_automatic(args.automatic) if args.automatic else None
    unit = spec.measurements.get("unit", "mm")
    ip = image_points(geoms, measured, res, auto, unit=unit)
    path = write_table(out / "image_points.csv", ip, list(CONTRACT_COLUMNS))
    write_table(out / "image_points_quality.csv", ip)
    acc = int(res["accepted"].sum())
    print(f"vectoradjust measure transfer: {acc} of {len(res['accepted'])} transfers "
          f"accepted ({len(res['accepted']) - acc} flagged, see {out / 'transfer.csv'})")
    _say_rpc(geoms)
    kind = "pixels" if unit == "pixel" else "photo mm"
    if spec.has_rpc:
        kind += ("; RPC images' rows in pixels" if unit != "pixel" else "")
    print(f"  wrote {path} ({len(ip['point_id'])} measurements, {kind})")
    return 0


def _write_settings(path: Path, st, sigma_height: float) -> None:
    """The thresholds of a transfer (every MatchSettings field and ``sigma_height``) as
    JSON; a non-finite number as its string (``"inf"``)."""
    import dataclasses

    vals = dict(dataclasses.asdict(st), sigma_height=sigma_height)
    vals = {k: (str(v) if isinstance(v, float) and not np.isfinite(v) else v)
            for k, v in vals.items()}
    path.write_text(json.dumps(vals, indent=1) + "\n", encoding="utf-8")


def _read_automatic(path) -> dict:
    import csv

    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    out = {k: np.array([r[k] for r in rows]) for k in ("point_id", "image_id")}
    for k in ("col", "row", "rms"):
        out[k] = np.array([float(r[k]) if r[k] else np.nan for r in rows])
    out["accepted"] = np.array([r["accepted"] == "True" for r in rows])
    return out

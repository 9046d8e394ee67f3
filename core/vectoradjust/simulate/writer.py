"""Writing a scenario as a project in the file contract (``docs/method.md`` section 9).

:func:`write_project` writes ``project.toml``, the CSV files, the road layers, the
truth, the DEM and the README (:func:`vectoradjust.simulate.readme.describe`).
geopandas, shapely, rasterio and pandas are imported only when writing.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from vectoradjust.errors import ProjectError
from vectoradjust.model import LineLayer
from vectoradjust.sensor.camera import CameraCalibration
from vectoradjust.simulate.container import Scenario
from vectoradjust.simulate.readme import describe


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} to TOML")


def _project_toml(sc: Scenario, layer_ext: str, camera_file: str | None = None,
                  reweight: str = "none") -> str:
    out = [
        f"# Simulated project written by vectoradjust.simulate (seed {sc.seed}); see README.md",
        f"name = {_toml_value('vectoradjust simulated scenario, seed ' + str(sc.seed))}",
        f"crs = {_toml_value(sc.crs)}",
        "",
        "[camera]",
    ]
    if camera_file is None:
        out += [f"focal_length = {_toml_value(sc.camera.focal_length)}",
                f"principal_point = {_toml_value(list(sc.camera.principal_point))}",
                "", "[corrections]", "refraction = false", "earth_curvature = false"]
    else:
        out += [f"path = {_toml_value(camera_file)}          # calibration (SIMULATED)",
                "", "[corrections]                   # undo the simulated effects"]
        out += [f"{k} = {_toml_value(v)}" for k, v in sc.default_corrections().items()]
    for im in sc.images:
        out += ["", "[[images]]", f"id = {_toml_value(im.id)}",
                f"position = {_toml_value([float(v) for v in im.position])}",
                f"attitude = {_toml_value([float(v) for v in im.attitude])}"]
        if im.sigma_position is not None:
            out.append(f"sigma_position = {_toml_value(float(im.sigma_position))}")
        if im.sigma_attitude is not None:
            out.append(f"sigma_attitude = {_toml_value(float(im.sigma_attitude))}")
        if im.date is not None:
            out.append(f"date = {_toml_value(im.date)}")
    out += ["", "[measurements]", 'path = "image_points.csv"']
    if sc.unit == "pixel":
        out += ['unit = "pixel"                  # x = column, y = row (scanner pixels)',
                f"sigma = {_toml_value(round(float(sc.measurements.sigma[0, 0]), 6))}"
                "          # pixels",
                'fiducials = "fiducials.csv"']
    else:
        out += [f"sigma = {_toml_value(sc.sigma_image)}"]
    out += ["", "[control]", 'path = "gcps.csv"']
    for name, spec in sc.vector_specs.items():
        stem = sc.databases[name].stem
        out += ["", "[[vectors]]", f"name = {_toml_value(name)}",
                f"path = {_toml_value(stem + '_roads.' + layer_ext)}",
                f"id_field = {_toml_value(spec.id_field)}",
                f"sigma = {_toml_value([float(s) for s in spec.sigma])}",
                f"dem = {_toml_value(spec.dem)}", f"truth = {_toml_value(spec.truth)}"]
        if spec.identification_sigma is not None:
            out.append("identification_sigma = "
                       f"{_toml_value([float(s) for s in spec.identification_sigma])}")
    rw = f"reweight = {_toml_value(reweight)}"
    if reweight == "two-pass":
        rw += "   # shape-point accuracy unknown: sigma <- RMS of pass-1 residuals"
    out += ["", "[adjustment]", "max_iterations = 20", rw, "alpha = 0.05"]
    out += ["", "[truth]   # simulated true centrelines: buffer test before/after the adjustment",
            f"path = {_toml_value('truth_roads.' + layer_ext)}", "widths = [1.0, 2.0]", ""]
    return "\n".join(out)


def _camera_toml(cal: CameraCalibration) -> str:
    """A camera file for a calibration that has no file of its own."""
    d = cal.to_dict()
    fid = d.pop("fiducials", None)
    dist = d.pop("distortion", None)
    out = ["# Camera calibration written by vectoradjust.simulate (SIMULATED values)"]
    out += [f"{k} = {_toml_value(v)}" for k, v in d.items()]
    if fid:
        out += ["", "[fiducials]"] + [f"{json.dumps(k)} = {_toml_value(v)}"
                                      for k, v in fid.items()]
    if dist:
        out += ["", "[distortion]"] + [f"{k} = {_toml_value(v)}" for k, v in dist.items()]
    return "\n".join(out) + "\n"


def _layer_frame(layer: LineLayer, crs: str):
    import geopandas as gpd
    import shapely

    xy = layer.coords[:, :2]
    key = layer.vertex_feature * (int(layer.vertex_part.max(initial=0)) + 1) + layer.vertex_part
    _, line_index = np.unique(key, return_inverse=True)
    line_index = np.asarray(line_index).reshape(-1)
    lines = shapely.linestrings(xy, indices=line_index)
    starts = np.searchsorted(line_index, np.arange(len(lines)))
    line_feature = layer.vertex_feature[starts]
    parts = np.bincount(line_feature, minlength=layer.n_features)
    geoms = np.empty(layer.n_features, dtype=object)
    single = parts == 1
    first_line = np.searchsorted(line_feature, np.arange(layer.n_features))
    geoms[single] = lines[first_line[single]]
    multi = np.nonzero(parts > 1)[0]
    if len(multi):
        sel = np.isin(line_feature, multi)
        # multi is sorted: consecutive indices 0..len(multi)-1 for shapely
        geoms[multi] = shapely.multilinestrings(
            lines[sel], indices=np.searchsorted(multi, line_feature[sel]))
    return gpd.GeoDataFrame(dict(layer.attributes), geometry=list(geoms), crs=crs)


def _write_csv(path: Path, header: str, columns: list, formats: list) -> None:
    import pandas as pd

    frame = pd.DataFrame({f"c{i}": c for i, c in enumerate(columns)})
    for i, fmt in enumerate(formats):
        if fmt is not None:
            frame[f"c{i}"] = np.char.mod(fmt, np.asarray(columns[i], float))
    with open(path, "w", encoding="utf-8", newline="") as fh:
        fh.write(header + "\n")
        frame.to_csv(fh, header=False, index=False, lineterminator="\n")


def write_project(scenario: Scenario, out_dir, *, format: str = "shp",
                  reweight: str = "none") -> Path:
    """Write the scenario as a project following the file contract (``docs/method.md`` section 9).

    Files: ``project.toml``, ``image_points.csv``, ``gcps.csv``, ``<stem>_roads.shp``
    per database (2D LineStrings / MultiLineStrings with every attribute),
    ``truth_roads.shp`` (true centrelines, 3D), ``truth_<stem>.csv`` per database
    (``point_id,X,Y,Z`` of every vertex; referenced as ``truth =`` in ``[[vectors]]``),
    ``truth_eo.csv`` and ``truth_points.csv`` (true EO, control/check/tie truth),
    ``dem.tif`` (float32 GeoTIFF, deflate) and ``README.md``. A scenario with a
    calibration also gets its camera file (``[camera] path``: a copy of the
    calibration's own file, or ``camera.toml`` written from it) and ``[corrections]``
    that undo the simulated effects; a scanned one ``fiducials.csv``
    (``image_id,fiducial_id,x,y`` in pixels) and ``[measurements] unit = "pixel"``.

    Parameters
    ----------
    scenario : Scenario
    out_dir : str or pathlib.Path
        Created if missing; existing files of the same names are overwritten.
    format : {"shp", "gpkg"}
        Format of the road layers.
    reweight : {"none", "two-pass", "vce"}
        ``[adjustment] reweight`` written to the project file.

    Returns
    -------
    pathlib.Path
        The written ``project.toml``.
    """
    # the geodata packages first: a missing one fails before anything is written
    import geopandas  # noqa: F401
    import rasterio  # noqa: F401
    import shapely  # noqa: F401

    if format not in ("shp", "gpkg"):
        raise ProjectError(f"unknown layer format {format!r}", "Use format 'shp' or 'gpkg'")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sc = scenario
    camera_file = _write_camera(sc, out)
    (out / "project.toml").write_text(_project_toml(sc, format, camera_file, reweight),
                                      encoding="utf-8")
    _write_measurements(sc, out)
    _write_roads(sc, out, format)
    _write_truth(sc, out)
    _write_dem(sc, out / "dem.tif")
    (out / "README.md").write_text(describe(sc, layer_ext=format, reweight=reweight),
                                   encoding="utf-8")
    return out / "project.toml"


def _write_measurements(sc: Scenario, out: Path) -> None:
    """``image_points.csv``, ``fiducials.csv`` (scanned scenarios) and ``gcps.csv``."""
    m = sc.measurements
    xf = "%.4f" if sc.unit == "pixel" else "%.6f"
    _write_csv(out / "image_points.csv", "point_id,image_id,x,y,sigma_x,sigma_y",
               [m.point_id, m.image_id, m.xy[:, 0], m.xy[:, 1], m.sigma[:, 0], m.sigma[:, 1]],
               [None, None, xf, xf, "%.6f", "%.6f"])
    if sc.fiducials is not None:
        f = sc.fiducials
        _write_csv(out / "fiducials.csv", "image_id,fiducial_id,x,y",
                   [f.image_id, f.fiducial_id, f.xy[:, 0], f.xy[:, 1]],
                   [None, None, "%.4f", "%.4f"])
    c = sc.control
    _write_csv(out / "gcps.csv", "point_id,X,Y,Z,sigma_x,sigma_y,sigma_z,role",
               [c.point_id, c.xyz[:, 0], c.xyz[:, 1], c.xyz[:, 2], c.sigma[:, 0], c.sigma[:, 1],
                c.sigma[:, 2], c.role],
               [None, "%.3f", "%.3f", "%.3f", "%.3f", "%.3f", "%.3f", None])


def _write_roads(sc: Scenario, out: Path, format: str) -> None:
    """Road layers and ``truth_<stem>.csv`` per database, and the true centrelines."""
    import geopandas as gpd
    import shapely

    driver = "ESRI Shapefile" if format == "shp" else "GPKG"
    for name, layer in sc.layers.items():
        stem = sc.databases[name].stem
        frame = _layer_frame(layer, sc.crs)
        frame.to_file(out / f"{stem}_roads.{format}", driver=driver)
        ids, xyz = sc.truth[name]
        _write_csv(out / f"truth_{stem}.csv", "point_id,X,Y,Z",
                   [ids, xyz[:, 0], xyz[:, 1], xyz[:, 2]], [None, "%.4f", "%.4f", "%.4f"])
    lines = sc.truth_lines
    sizes = np.array([len(a) for a in lines])
    geom = shapely.linestrings(np.concatenate(lines), indices=np.repeat(np.arange(len(lines)),
                                                                          sizes))
    gpd.GeoDataFrame(dict(sc.truth_line_attributes), geometry=list(geom), crs=sc.crs).to_file(
        out / f"truth_roads.{format}", driver=driver)


def _write_truth(sc: Scenario, out: Path) -> None:
    """``truth_eo.csv`` (true exterior orientation) and ``truth_points.csv``."""
    eo = sc.true_eo
    _write_csv(out / "truth_eo.csv", "image_id,XL,YL,ZL,omega,phi,kappa",
               [[im.id for im in sc.images], eo[:, 0], eo[:, 1], eo[:, 2],
                np.degrees(eo[:, 3]), np.degrees(eo[:, 4]), np.degrees(eo[:, 5])],
               [None, "%.4f", "%.4f", "%.4f", "%.6f", "%.6f", "%.6f"])
    c = sc.control
    pts_id = np.concatenate([c.point_id, sc.tie_ids]).astype(str)
    pts = np.concatenate([sc.control_true, sc.tie_true]).reshape(-1, 3)
    kind = np.concatenate([c.role, np.full(len(sc.tie_ids), "tie", dtype=object)])
    _write_csv(out / "truth_points.csv", "point_id,X,Y,Z,role",
               [pts_id, pts[:, 0], pts[:, 1], pts[:, 2], kind],
               [None, "%.4f", "%.4f", "%.4f", None])


def _write_dem(sc: Scenario, path: Path) -> None:
    """The DEM as a float32 GeoTIFF (deflate, floating-point predictor)."""
    import rasterio
    from rasterio.transform import Affine

    rows, cols = sc.dem_grid.shape
    with rasterio.open(
        path, "w", driver="GTiff", height=rows, width=cols, count=1,
        dtype="float32", crs=sc.crs, transform=Affine.from_gdal(*sc.dem_transform),
        nodata=sc.dem_nodata, compress="deflate", predictor=3,
    ) as dst:
        dst.write(sc.dem_grid.astype(np.float32), 1)


def _write_camera(sc: Scenario, out: Path) -> str | None:
    """Write (or copy) the scenario's camera file into ``out``; its name, or None."""
    cal = sc.calibration
    if cal is None:
        return None
    src = Path(cal.source) if cal.source else None
    if (src is not None and src.is_file()
            and CameraCalibration.from_file(src).to_dict() == cal.to_dict()):
        dst = out / src.name
        if not (dst.exists() and dst.resolve() == src.resolve()):
            dst.write_bytes(src.read_bytes())
        return src.name
    (out / "camera.toml").write_text(_camera_toml(cal), encoding="utf-8")
    return "camera.toml"

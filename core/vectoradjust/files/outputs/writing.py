"""Writing the layers, ``flagged_observations.csv`` and ``summary.json``: write_outputs.

The layers go to ``adjusted.gpkg`` (or shapefiles); :func:`write_outputs` is the entry.

Everything is written to a staging folder first and moved into place only when all
files were written (:class:`~vectoradjust.files.outputs.run_folder.RunFolder`), so a
failing run leaves nothing half-written. GDAL's warnings become run warnings.
"""

from __future__ import annotations

import json
import re
import warnings
from contextlib import contextmanager
from pathlib import Path
from typing import Optional

from vectoradjust.errors import CancelledError, InputFileError
from vectoradjust.files.jsonfile import (
    FEATURE_ACCURACY_CSV,
    clean_json,
    move_feature_statements,
)
from vectoradjust.files.outputs.fields import (
    renamed_input_fields,
    run_input_fields,
    storable_frame,
)
from vectoradjust.files.outputs.frames import (
    control_points_frame,
    features_frame,
    shape_points_frame,
    shape_points_table,
)
from vectoradjust.files.outputs.run_folder import RunFolder, json_default
from vectoradjust.results import AdjustmentRun

__all__ = [
    "write_outputs",
    "FLAGGED_COLUMNS",
]


_LAUNDERED = re.compile(r"Normalized/laundered field name: '(.+)' to '(.+)'")
_TRUNCATED_VALUE = re.compile(r"Value '.*' of field (\S+) has been truncated to (\d+) characters",
                              re.DOTALL)


def _writer_warning(message: str, where: str) -> Optional[str]:
    """A GDAL/pyogrio/geopandas warning raised while writing, as a run warning (or None)."""
    msg = " ".join(str(message).split())
    if msg.startswith("Column names longer than 10 characters"):
        return None  # geopandas' generic notice; GDAL names every laundered field
    m = _LAUNDERED.search(msg)
    if m:
        return (f"{where}: input field {m.group(1)!r} is written as {m.group(2)!r} "
                f"(shapefile field names have at most 10 characters; use --format gpkg to "
                f"keep the name)")
    m = _TRUNCATED_VALUE.search(msg)
    if m:
        return (f"{where}: text values of field {m.group(1)!r} are cut to {m.group(2)} "
                f"characters (the shapefile limit; use --format gpkg to keep them whole)")
    if len(msg) > 300:
        msg = msg[:300] + "..."
    return f"{where}: {msg}"


def _arrow_writing() -> dict:
    """``{"use_arrow": True}`` where pyogrio can write through Arrow (pyarrow installed:
    columns go to GDAL in bulk, not feature by feature), else ``{}``."""
    try:
        import pyarrow  # noqa: F401
    except ImportError:
        return {}
    return {"use_arrow": True}


@contextmanager
def _unsynced_sqlite():
    """GeoPackage writing without SQLite's wait for the disk after every transaction
    (``OGR_SQLITE_SYNCHRONOUS=OFF``), the setting before restored afterwards.

    :func:`write_outputs` writes into a temporary folder and moves the files into place
    only when all are written, so an interrupted run leaves no half-written GeoPackage
    among the outputs; the files are then as safe as any other file written without
    ``fsync`` (the CSV files, summary.json)."""
    try:
        from pyogrio import get_gdal_config_option, set_gdal_config_options
    except ImportError:
        yield
        return
    old = get_gdal_config_option("OGR_SQLITE_SYNCHRONOUS")
    set_gdal_config_options({"OGR_SQLITE_SYNCHRONOUS": "OFF"})
    try:
        yield
    finally:
        set_gdal_config_options({"OGR_SQLITE_SYNCHRONOUS": old})


def _write_layer(gdf, path: Path, layer: Optional[str], fmt: str) -> list:
    """Write one layer; returns GDAL's warnings as run warnings instead of printing them,
    and what the format cannot hold and was written otherwise (:func:`storable_frame`)."""
    where = f"{path.name} layer {layer}" if layer else path.name
    out: list = []
    if not hasattr(gdf, "write"):
        gdf, out = storable_frame(gdf, fmt, where)
    with warnings.catch_warnings(record=True) as caught, _unsynced_sqlite():
        warnings.simplefilter("always")
        if hasattr(gdf, "write"):  # a LayerTable (Arrow, WKB): straight to GDAL
            gdf.write(path, layer, "GPKG" if fmt == "gpkg" else "ESRI Shapefile")
        elif fmt == "gpkg":  # the features keep their LineString / MultiLineString
            keep = {"promote_to_multi": False} if layer == "features" else {}
            gdf.to_file(path, layer=layer, driver="GPKG", engine="pyogrio", **_arrow_writing(),
                        **keep)
        else:  # through Arrow too: int64, dates and booleans keep their DBF types
            gdf.to_file(path, driver="ESRI Shapefile", engine="pyogrio", encoding="UTF-8",
                        **_arrow_writing())
    for w in caught:
        text = _writer_warning(str(w.message), where)
        if text and text not in out:
            out.append(text)
    return out


FLAGGED_COLUMNS = ["kind", "image", "point", "point_kind", "component", "unit", "residual", "w",
                   "redundancy", "suspected_error", "mdb", "line", "observation"]


def _write_flagged(rows: list, path: Path) -> None:
    """The flagged observations (w-test) as CSV, largest |w| first."""
    import csv

    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=FLAGGED_COLUMNS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in FLAGGED_COLUMNS})


def _ready(frame, step, name: str):
    """The frame itself, or the result of a deferred one (``frame(progress)``)."""
    if not callable(frame):
        return frame
    step(f"building the {name} layer")
    return frame(step.within)


class _Steps:
    """Progress and cancel between the stages of :func:`write_outputs`."""

    def __init__(self, progress, is_cancelled, total: int) -> None:
        self.progress, self.is_cancelled, self.total, self.n = progress, is_cancelled, total, 0

    def __call__(self, message: str) -> None:
        if self.is_cancelled is not None and self.is_cancelled():
            raise CancelledError("Writing the outputs was cancelled", "Run it again when ready")
        if self.progress is not None:
            self.progress(min(0.95, self.n / self.total), message)
        self.n += 1

    def within(self, fraction: float, message: str) -> None:
        """Progress inside the current step (``fraction`` of it done)."""
        if self.progress is not None:
            self.progress(min(0.95, (self.n - 1 + fraction) / self.total), message)


def write_outputs(run: AdjustmentRun, out_dir, fmt: str = "gpkg",
                  extra_json: Optional[dict] = None, bands: bool = True,
                  progress=None, is_cancelled=None) -> dict:
    """Write ``adjusted.gpkg`` (or four shapefiles) and ``summary.json`` into ``out_dir``.

    The files are written into a staging folder and moved into place only when all are
    written (:class:`RunFolder`). Called while a :class:`RunFolder` of ``out_dir`` (or of a
    folder holding it) is open in this process, they go into its staging folder and its
    commit moves them, with the run's other files; otherwise this call is a run of its
    own: ``out_dir`` is locked, the files move into place at the end, the previous run's
    files that this one did not write (another format) are removed and
    :data:`MANIFEST` is written last.

    Parameters
    ----------
    run : AdjustmentRun
    out_dir : str or os.PathLike
        Created if missing; existing outputs of the same names are replaced.
    fmt : {"gpkg", "shp"}
    extra_json : dict, optional
        More keys for summary.json.
    bands : bool or callable
        Also write the ``uncertainty_bands`` layer (90 % G-band of every measured
        road segment, Shi & Liu 2000). A callable ``bands(progress)`` returns that
        layer's frame when it is needed, after the other layers are written (the command
        line builds it in a second process meanwhile).
    progress : callable, optional
        ``progress(fraction, message)`` before each table is built and each layer written.
    is_cancelled : callable, optional
        Polled at the same points; true raises :class:`CancelledError` and nothing of
        this call is left in ``out_dir``.

    Returns
    -------
    dict
        Paths written (where they end up), by name.

    Raises
    ------
    InputFileError
        The format is unknown, ``out_dir`` cannot be written, another run is writing
        into it, or the disk is full (the previous result is then left as it was).
    """
    if fmt not in ("gpkg", "shp"):
        raise InputFileError(f"Output format {fmt!r} is not supported", "Use gpkg or shp")
    out = Path(out_dir)
    folder = RunFolder.holding(out)
    if folder is not None:
        written = _write_staged(run, folder, out, fmt, extra_json, bands, progress,
                                is_cancelled)
    else:
        with RunFolder(out, command="write_outputs") as own:
            written = _write_staged(run, own, out, fmt, extra_json, bands, progress,
                                    is_cancelled)
            own.commit()
    if progress is not None:
        progress(1.0, "outputs written")
    return written


def _frames(run: AdjustmentRun, bands, step, is_cancelled) -> dict:
    """The layers to write, by name (tables, or callables building them when needed)."""
    frames = {}
    for name, make in (("shape_points", shape_points_frame), ("features", features_frame),
                       ("control_points", control_points_frame)):
        step(f"building the {name} table")
        table = None
        if name == "shape_points" and run.databases and _arrow_writing():
            table = shape_points_table(run)  # straight to GDAL's Arrow interface
        frames[name] = table if table is not None else make(run)
    if callable(bands) and run.databases:  # built elsewhere: asked for when written
        frames["uncertainty_bands"] = bands
    elif bands and run.databases:
        from vectoradjust.files.derived_outputs import uncertainty_bands_frame

        step("building the uncertainty_bands layer")
        frames["uncertainty_bands"] = uncertainty_bands_frame(
            run, progress=step.within, is_cancelled=is_cancelled)
    return frames


def _write_layers(frames: dict, tmp: Path, fmt: str, step) -> tuple:
    """Every layer into ``tmp``; (file names, GDAL's warnings). Each table is let go once
    written: the memory of a written layer is free for the next one (the bands layer,
    last, waits for its processes meanwhile)."""
    notes: list = []
    names: list = []
    for name in list(frames):
        gdf = _ready(frames.pop(name), step, name)
        if fmt == "gpkg":
            step(f"writing the {name} layer")
            notes += _write_layer(gdf, tmp / "adjusted.gpkg", name, fmt)
        else:
            step(f"writing {name}.shp")
            notes += _write_layer(gdf, tmp / f"{name}.shp", None, fmt)
            names += [p.name for p in tmp.glob(f"{name}.*")]
        del gdf
    return (["adjusted.gpkg"] if fmt == "gpkg" else names), notes


def _write_staged(run: AdjustmentRun, folder: RunFolder, out: Path, fmt: str,
                  extra_json: Optional[dict], bands, progress, is_cancelled) -> dict:
    """The files of :func:`write_outputs` written into ``folder``'s staging folder."""
    step = _Steps(progress, is_cancelled, 8 if bands and run.databases else 7)
    frames = _frames(run, bands, step, is_cancelled)
    tmp = folder.staged(out)
    tmp.mkdir(parents=True, exist_ok=True)
    names, notes = _write_layers(frames, tmp, fmt, step)
    if notes:  # into the run's warnings (printed, in summary.json and the report)
        run.summary["warnings"] = list(run.summary.get("warnings", [])) + notes
    if run.flagged:
        _write_flagged(run.flagged, tmp / "flagged_observations.csv")
        names.append("flagged_observations.csv")
    if any(im.model == "rpc" for im in run.data.images):
        from vectoradjust.files.rpc import write_corrected_rpcs

        names += write_corrected_rpcs(run, tmp, out)  # also notes them in the summary
    step("writing summary.json")
    summary = dict(run.summary)
    summary["renamed_input_fields"] = renamed_input_fields(run_input_fields(run))
    if extra_json:
        summary.update(extra_json)
    summary, feature_csv = move_feature_statements(summary, tmp)  # summary.json bounded
    if feature_csv is not None:
        names.append(feature_csv.name)
    with open(tmp / "summary.json", "w", encoding="utf-8") as fh:
        json.dump(clean_json(summary), fh, indent=2, default=json_default)
    names.append("summary.json")
    # an earlier run's, when this one has none: removed by the commit
    folder.claim("flagged_observations.csv", FEATURE_ACCURACY_CSV, under=out)
    return {n: str(out / n) for n in names}

"""``adjust-many``'s merged output: one GeoPackage per database, :class:`MergedOutput`.

A county of stereo models adjusted by :func:`vectoradjust.files.many.adjust_many` is one
folder per model; the merged output puts the rows of every model's layers
(``shape_points`` and ``features``; ``uncertainty_bands`` on request) into one file per
database, ``DIR/merged_<database>.gpkg``, with a ``project`` column (:data:`PROJECT_COLUMN`)
naming the model each row came from. Every other field has the name and type of the
per-project layer (int64 ids stay int64, dates stay dates).

How the rows travel: the worker that adjusted a model reads its own layers back
(:func:`project_layers`, Arrow tables as GDAL wrote them, so the fields are exactly the
per-project layers') and returns them with the model's summary row; the parent
(:class:`MergedOutput`, the only writer) appends them as each model finishes and lets
them go. So the merged files are written on the client's disk even when a cluster's
workers write the per-project folders on disks of their own, and never more than the
models in flight are held in memory.

The merged files are written beside their place (``.merged_<database>.part.gpkg``) and
moved there by :meth:`MergedOutput.commit` when every model is in: an interrupted run
leaves the earlier merged files as they were; a complete one replaces them all (an
earlier ``merged_<database>.gpkg`` of a database without rows now is removed).
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Optional

__all__ = ["MERGE_LAYERS", "PROJECT_COLUMN", "MergedOutput", "project_layers",
           "merged_path", "merged_row_count"]

#: the layers merged by default (``uncertainty_bands`` too with ``layers=``)
MERGE_LAYERS = ("shape_points", "features")
#: the column naming the project (stereo model) of each merged row
PROJECT_COLUMN = "project"


def merged_path(out_dir, database: str) -> Path:
    """``out_dir/merged_<database>.gpkg`` (the database's name made safe for file names)."""
    safe = re.sub(r"[^\w.-]+", "_", str(database)).strip("._") or "database"
    return Path(out_dir) / f"merged_{safe}.gpkg"


def _layer_source(out_dir: Path, layer: str, fmt: str) -> tuple:
    """(file, layer name or None) of a project's layer as ``adjust`` writes it."""
    if fmt == "gpkg":
        return out_dir / "adjusted.gpkg", layer
    return out_dir / f"{layer}.shp", None


def project_layers(out_dir, name: str, fmt: str = "gpkg",
                   layers: Sequence[str] = MERGE_LAYERS) -> list:
    """The layers of a project folder just written, split by database, for merging.

    Parameters
    ----------
    out_dir : str or os.PathLike
        The project's folder (``adjusted.gpkg`` or the shapefiles).
    name : str
        The project's name: the value of the :data:`PROJECT_COLUMN` column.
    fmt : {"gpkg", "shp"}
    layers : sequence of str
        Layers to read; one missing (e.g. no ``uncertainty_bands``) is skipped.

    Returns
    -------
    list of tuple
        ``(database, layer, table, meta)``: a ``pyarrow.Table`` (geometry as WKB) with
        the project column first, and ``meta`` (``crs``, ``geometry_type``,
        ``geometry_name``) for writing it.
    """
    import pyarrow as pa
    import pyarrow.compute as pc
    from pyogrio import list_layers, read_arrow

    out: list = []
    for layer in layers:
        path, lyr = _layer_source(Path(out_dir), layer, fmt)
        if not path.exists() or (lyr is not None and lyr not in list_layers(path)[:, 0]):
            continue
        info, table = read_arrow(path, layer=lyr)
        table = table.combine_chunks()  # one buffer per column: cheap to ship and filter
        meta = {"crs": info.get("crs"), "geometry_type": info.get("geometry_type"),
                "geometry_name": info.get("geometry_name") or "wkb_geometry"}
        column = _project_column(table.column_names)
        table = table.add_column(0, column, pa.array([name] * table.num_rows, pa.string()))
        by = next((c for c in ("Database", "database") if c in table.column_names), None)
        dbs = pc.unique(table[by]).to_pylist() if by else [None]  # the bands: "database"
        for db in dbs:
            part = table if len(dbs) == 1 else table.filter(pc.equal(table[by], db))
            out.append((db if db is not None else "all", layer, part, meta))
    return out


def _project_column(names: Sequence[str]) -> str:
    """:data:`PROJECT_COLUMN`, or ``many_project`` where an input field has that name."""
    return PROJECT_COLUMN if PROJECT_COLUMN not in names else "many_project"


class MergedOutput:
    """One GeoPackage per database, appended to as each project's layers arrive.

    Only the parent writes (one writer per file); :meth:`add` appends a project's
    tables (:func:`project_layers`) and returns how many rows it merged,
    :meth:`commit` moves the files into place, :meth:`discard` removes them.
    ``notes`` lists what could not be merged as it was (a field one project has and the
    first did not, a value of another type).

    Parameters
    ----------
    out_dir : str or os.PathLike
        Where ``merged_<database>.gpkg`` go.
    """

    def __init__(self, out_dir) -> None:
        self.out = Path(out_dir)
        self.parts: dict = {}  # database -> staged file
        self.schemas: dict = {}  # (database, layer) -> the layer's Arrow schema
        self.rows: dict = {}  # (database, layer) -> rows written
        self.notes: list = []

    def add(self, name: str, tables: Sequence) -> int:
        """Append one project's tables; the number of rows merged."""
        from pyogrio import write_arrow

        n = 0
        for db, layer, table, meta in tables:
            if table.num_rows == 0:
                continue
            key = (db, layer)
            if db not in self.parts:
                self.parts[db] = self._staged(db)
            part = self.parts[db]
            if key in self.schemas:
                table = self._conform(table, self.schemas[key], name, db, layer)
            else:
                self.schemas[key] = table.schema
            # append: to the layer, or a new layer to the file (else GDAL starts it anew)
            write_arrow(table, part, layer=layer, driver="GPKG", append=part.exists(),
                        crs=meta["crs"], geometry_type=meta["geometry_type"],
                        geometry_name=meta["geometry_name"])
            self.rows[key] = self.rows.get(key, 0) + table.num_rows
            n += table.num_rows
        return n

    def _staged(self, db: str) -> Path:
        final = merged_path(self.out, db)
        part = final.with_name(f".{final.stem}.part.gpkg")
        if part.exists():  # left by an interrupted run
            part.unlink()
        return part

    def _conform(self, table, schema, name: str, db: str, layer: str):
        """``table`` with ``schema``'s fields, in its order: a missing field is null, a
        field the layer does not have is left out (noted), another type is cast (else
        null, noted)."""
        import pyarrow as pa

        if table.schema.equals(schema):
            return table
        extra = [c for c in table.column_names if c not in schema.names]
        if extra:
            self.notes.append(f"{name}: {layer} fields {extra} of {db} are not in the merged "
                              f"layer (the first project's fields); see {name}'s own layer")
        cols = []
        for field in schema:
            if field.name not in table.column_names:
                cols.append(pa.nulls(table.num_rows, field.type))
                continue
            col = table[field.name]
            if col.type != field.type:
                try:
                    col = col.cast(field.type)
                except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
                    self.notes.append(f"{name}: {layer} field {field.name!r} of {db} is "
                                      f"{col.type}, not {field.type}: merged as null")
                    col = pa.nulls(table.num_rows, field.type)
            cols.append(col)
        return pa.Table.from_arrays(cols, schema=schema)

    def commit(self) -> dict:
        """Move every merged file into place; ``{database: path}``. An earlier run's
        ``merged_*.gpkg`` of a database this run has no rows of is removed (the merged
        files are this run's projects, no others)."""
        out = {}
        for db, part in self.parts.items():
            final = merged_path(self.out, db)
            os.replace(part, final)
            out[db] = str(final)
        self.parts = {}
        for old in self.out.glob("merged_*.gpkg"):
            if str(old) not in out.values():
                old.unlink()
        return out

    def discard(self) -> None:
        """Remove the staged files (a run that did not finish)."""
        for part in self.parts.values():
            if part.exists():
                part.unlink()
        self.parts = {}

    def counts(self) -> dict:
        """``{"<database>/<layer>": rows}`` written so far."""
        return {f"{db}/{layer}": n for (db, layer), n in sorted(self.rows.items())}


def merged_row_count(path, layer: str) -> Optional[int]:
    """Rows of a merged layer (None when the layer is not in the file)."""
    from pyogrio import list_layers, read_info

    if layer not in list_layers(path)[:, 0]:
        return None
    return int(read_info(path, layer=layer)["features"])

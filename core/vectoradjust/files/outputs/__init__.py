"""Writing the contract's outputs: ``adjusted.gpkg`` (or shapefiles) and ``summary.json``.

Everything is written to a temporary directory first and moved into place only when
all files were written, so a failing run leaves nothing half-written. A whole run
(the command line's layers, tables, report, ...) is written the same way through
:class:`RunFolder`: its output folder locked (:class:`DirLock`), the files staged and
moved into place at the end, ``run_manifest.json`` (:data:`MANIFEST`) last.

The package's modules:

- :mod:`~vectoradjust.files.outputs.writing` - :func:`write_outputs`: the layers,
  ``flagged_observations.csv`` and ``summary.json`` written into the staging folder;
  GDAL's warnings as run warnings.
- :mod:`~vectoradjust.files.outputs.frames` - the layers as tables:
  :func:`shape_points_frame`, :func:`features_frame`, :func:`control_points_frame`.
- :mod:`~vectoradjust.files.outputs.fields` - the fields: the contract's names, renamed
  input attributes, attribute types, what a format cannot hold (:func:`field_change`,
  :func:`storable_frame`).
- :mod:`~vectoradjust.files.outputs.run_folder` - :class:`RunFolder`, :class:`DirLock`,
  the manifest, a full disk.

The package re-exports every public name of its modules (and ``_write_layer``, which
tests use). A patched name must be patched in the module that looks it up (e.g.
``shape_points_table``, ``_arrow_writing`` and ``_write_layer`` in ``writing``).
"""

from __future__ import annotations

from vectoradjust.files.outputs.fields import (
    CONTROL_FIELDS,
    FEATURE_FIELDS,
    FIELD_KINDS,
    RESERVED_NAMES,
    SHAPE_FIELDS,
    SHAPEFILE_INT32_DIGITS,
    SHAPEFILE_INTEGER_DIGITS,
    SHAPEFILE_NAME_LENGTH,
    SHAPEFILE_REAL_DECIMALS,
    attribute_array,
    field_change,
    input_field_types,
    renamed_input_fields,
    run_input_fields,
    storable_frame,
    text_value,
)
from vectoradjust.files.outputs.frames import (
    control_points_frame,
    features_frame,
    shape_points_frame,
    shape_points_table,
)
from vectoradjust.files.outputs.run_folder import (
    LOCK_NAME,
    MANIFEST,
    NEARLY_FULL_BYTES,
    DirLock,
    RunFolder,
    is_disk_full,
    json_default,
    read_manifest,
)
from vectoradjust.files.outputs.writing import (
    FLAGGED_COLUMNS,
    write_outputs,
)
from vectoradjust.files.outputs.writing import _write_layer as _write_layer

__all__ = ["write_outputs", "shape_points_frame", "features_frame", "control_points_frame",
           "json_default", "renamed_input_fields", "run_input_fields", "input_field_types",
           "attribute_array", "storable_frame", "field_change", "text_value", "FIELD_KINDS",
           "RunFolder", "DirLock", "MANIFEST", "LOCK_NAME", "is_disk_full", "read_manifest",
           # the fields and limits of the contract, public in the modules too
           "SHAPE_FIELDS", "FEATURE_FIELDS", "CONTROL_FIELDS", "RESERVED_NAMES",
           "SHAPEFILE_NAME_LENGTH", "SHAPEFILE_INTEGER_DIGITS", "SHAPEFILE_INT32_DIGITS",
           "SHAPEFILE_REAL_DECIMALS", "FLAGGED_COLUMNS", "NEARLY_FULL_BYTES",
           "shape_points_table"]

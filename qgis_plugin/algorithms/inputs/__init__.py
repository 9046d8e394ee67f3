"""Parameters and input assembly shared by "Adjust road vectors" and "Compare road databases".

The camera, images, measurements, control and settings come from a project file
(TOML, the contract of ``docs/method.md`` section 9) and/or from parameters. A parameter
that is set wins over the project file; what neither gives is an error with the
core's message. The project file is validated by the core
(:func:`vectoradjust.files.project.parse_project`), and a parameter-only set-up is validated
the same way, so both routes give the same checks and the same numbers.

Every ``[[vectors]]`` entry of the project file is read through QGIS (as the command
line reads them all), so that measurements of the databases that are not adjusted are
recognised and left out rather than taken for tie points. A road layer that stands for an
entry (its file, its name or its ids: :mod:`.matching`) takes that entry's place, name, id
field, sigma, DEM and truth unless parameters say otherwise; a road layer that is not in
the project is one more database. The tables are assembled into the core's ProjectData by
:func:`vectoradjust.files.assemble.project_data`, the function the command line uses.

The package's modules:

- :mod:`.parameters` - the shared parameters: names, help texts,
  ``add_project_parameters``, ``add_road_parameters``.
- :mod:`.project_file` - the project file and the overriding parameters as
  ``ProjectInputs``; the parameter readers ``_is_set`` and ``_number``.
- :mod:`.road_layers` - road layers and the project's ``[[vectors]]`` entries read
  through QGIS, assembled into the core's ProjectData.
- :mod:`.adjustment` - ``run_adjustment``: one adjustment from the dialog's parameters.

The package re-exports the public names of its modules and the private ones the other
algorithms and the tests use (``_is_set``, ``_number``, ``_read_toml``, ``_refuse_datums``,
``_REWEIGHT_VALUES``).
"""

from .adjustment import (
    Adjusted,
    road_error_model,
    run_adjustment,
)
from .parameters import _REWEIGHT_VALUES as _REWEIGHT_VALUES
from .parameters import (
    ALPHA,
    CONTROL,
    DEM,
    FOCAL_LENGTH,
    GROUND_CRS,
    ID_FIELD,
    IDENT_XY,
    IDENT_Z,
    IMAGE_HEADERS,
    IMAGES,
    INPUT,
    MAX_ITERATIONS,
    MEASUREMENT_SIGMA,
    MEASUREMENTS,
    NAME,
    OFFSET,
    OFFSET_CHOICES,
    PP_X,
    PP_Y,
    PROJECT,
    PROJECT_HELP,
    REWEIGHT,
    REWEIGHT_OPTIONS,
    ROAD_HELP,
    SIGMA_XY,
    SIGMA_Z,
    add_project_parameters,
    add_road_parameters,
)
from .project_file import (
    ProjectInputs,
    matching_vector_spec,
    project_inputs,
    raster_from_path,
)
from .project_file import _is_set as _is_set
from .project_file import _number as _number
from .project_file import _read_toml as _read_toml
from .project_file import _refuse_datums as _refuse_datums
from .road_layers import (
    RoadDatabase,
    entry_settings_text,
    filtered_entry_layer,
    open_vector_entry,
    project_data_with,
    read_project_entry,
    read_road_layer,
    shape_point_sigma,
)

__all__ = [
    "PROJECT",
    "MEASUREMENTS",
    "MEASUREMENT_SIGMA",
    "CONTROL",
    "FOCAL_LENGTH",
    "PP_X",
    "PP_Y",
    "IMAGES",
    "GROUND_CRS",
    "REWEIGHT",
    "ALPHA",
    "MAX_ITERATIONS",
    "IMAGE_HEADERS",
    "REWEIGHT_OPTIONS",
    "PROJECT_HELP",
    "add_project_parameters",
    "ROAD_HELP",
    "INPUT",
    "ID_FIELD",
    "NAME",
    "DEM",
    "SIGMA_XY",
    "SIGMA_Z",
    "IDENT_XY",
    "IDENT_Z",
    "OFFSET",
    "OFFSET_CHOICES",
    "add_road_parameters",
    "ProjectInputs",
    "project_inputs",
    "matching_vector_spec",
    "raster_from_path",
    "RoadDatabase",
    "shape_point_sigma",
    "read_road_layer",
    "open_vector_entry",
    "filtered_entry_layer",
    "read_project_entry",
    "project_data_with",
    "entry_settings_text",
    "road_error_model",
    "Adjusted",
    "run_adjustment",
]

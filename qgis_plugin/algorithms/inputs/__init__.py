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

from . import adjustment, parameters, project_file, road_layers
from .adjustment import Adjusted as Adjusted
from .adjustment import road_error_model as road_error_model
from .adjustment import run_adjustment as run_adjustment
from .parameters import _REWEIGHT_VALUES as _REWEIGHT_VALUES
from .parameters import ALPHA as ALPHA
from .parameters import CONTROL as CONTROL
from .parameters import DEM as DEM
from .parameters import FOCAL_LENGTH as FOCAL_LENGTH
from .parameters import GROUND_CRS as GROUND_CRS
from .parameters import ID_FIELD as ID_FIELD
from .parameters import IDENT_XY as IDENT_XY
from .parameters import IDENT_Z as IDENT_Z
from .parameters import IMAGE_HEADERS as IMAGE_HEADERS
from .parameters import IMAGES as IMAGES
from .parameters import INPUT as INPUT
from .parameters import MAX_ITERATIONS as MAX_ITERATIONS
from .parameters import MEASUREMENT_SIGMA as MEASUREMENT_SIGMA
from .parameters import MEASUREMENTS as MEASUREMENTS
from .parameters import NAME as NAME
from .parameters import OFFSET as OFFSET
from .parameters import OFFSET_CHOICES as OFFSET_CHOICES
from .parameters import PP_X as PP_X
from .parameters import PP_Y as PP_Y
from .parameters import PROJECT as PROJECT
from .parameters import PROJECT_HELP as PROJECT_HELP
from .parameters import REWEIGHT as REWEIGHT
from .parameters import REWEIGHT_OPTIONS as REWEIGHT_OPTIONS
from .parameters import ROAD_HELP as ROAD_HELP
from .parameters import SIGMA_XY as SIGMA_XY
from .parameters import SIGMA_Z as SIGMA_Z
from .parameters import add_project_parameters as add_project_parameters
from .parameters import add_road_parameters as add_road_parameters
from .project_file import ProjectInputs as ProjectInputs
from .project_file import _is_set as _is_set
from .project_file import _number as _number
from .project_file import _read_toml as _read_toml
from .project_file import _refuse_datums as _refuse_datums
from .project_file import matching_vector_spec as matching_vector_spec
from .project_file import project_inputs as project_inputs
from .project_file import raster_from_path as raster_from_path
from .road_layers import RoadDatabase as RoadDatabase
from .road_layers import entry_settings_text as entry_settings_text
from .road_layers import filtered_entry_layer as filtered_entry_layer
from .road_layers import open_vector_entry as open_vector_entry
from .road_layers import project_data_with as project_data_with
from .road_layers import read_project_entry as read_project_entry
from .road_layers import read_road_layer as read_road_layer
from .road_layers import shape_point_sigma as shape_point_sigma

# the submodules' own lists (one place for each name)
__all__ = [*parameters.__all__, *project_file.__all__, *road_layers.__all__,
           *adjustment.__all__]

"""vectoradjust: photogrammetric adjustment of road vectors.

The subpackages follow the data through the program (``docs/architecture.md``):
:mod:`~vectoradjust.sensor` (image coordinates and the sensor model) ->
:mod:`~vectoradjust.adjust` (shape points and the bundle adjustment) ->
:mod:`~vectoradjust.accuracy` (statistics and derived quantities) ->
:mod:`~vectoradjust.conflation` (the databases corrected: unmeasured vertices, several
databases feature by feature) ->
:mod:`~vectoradjust.qa` (production accuracy control); :mod:`vectoradjust.pipeline` runs
one adjustment on in-memory data by calling those stages; :mod:`~vectoradjust.files`
reads and writes, :mod:`~vectoradjust.runner` takes a project file to a finished output
folder (:func:`run_project`), :mod:`~vectoradjust.cli` is the command line and
:mod:`~vectoradjust.simulate` makes projects with known truth.

Everything below :mod:`vectoradjust.pipeline` imports only numpy and scipy. File input
and output (geopandas, pyogrio, rasterio, pyproj) live in :mod:`vectoradjust.files` and
are imported lazily, so that QGIS can use the heart without loading a second GDAL.

The names below are the public API; they are imported when first used, so that
``import vectoradjust`` stays cheap:

- :func:`read_project` (a project file and the files it names, as a :class:`Project`),
  :func:`run_project` (a project to a finished output folder, as ``vectoradjust adjust``
  does), :class:`RunOptions` (what ``adjust``'s flags set), :class:`ProjectResult` (what
  it made: ``run``, ``written``, ``qa``, ``notes``), :class:`AdjustmentRun` (the
  adjustment and its statistics), :class:`ProjectData` (the inputs as arrays),
  :func:`sample_project_dir` (the embedded sample project);
- the errors: :class:`VectorAdjustError` and its subclasses (:class:`ProjectError`,
  :class:`InputFileError`, :class:`CRSError`, :class:`ControlError`, ...), each saying
  what was wrong and how to mend it, and :class:`CancelledError`.

(The adjustment of data in memory is :func:`vectoradjust.pipeline.run`; it is not named
``vectoradjust.adjust``, which is the subpackage of the bundle adjustment.)

Examples
--------
>>> import vectoradjust
>>> project = vectoradjust.read_project(vectoradjust.sample_project_dir() / "project.toml")
>>> [spec.name for spec, layer in project.data.vectors]
['OSM', 'TNM', 'TIGER']
>>> import tempfile
>>> out = tempfile.mkdtemp()
>>> done = vectoradjust.run_project(project, out,
...                                 vectoradjust.RunOptions(bands=False, report=False))
>>> round(done.summary["sigma0_squared"], 2), done.summary["chi_square"]["passed"]
(0.97, True)
>>> sorted(done.written)
['adjusted.gpkg', 'feature_accuracy.csv', 'flagged_observations.csv', 'summary.json', \
'truth_line_points.csv', 'truth_points.csv']

A wrong project says what is wrong and how to mend it:

>>> try:
...     vectoradjust.read_project("missing.toml")
... except vectoradjust.ProjectError as exc:
...     print(exc.what)
Project file 'missing.toml' does not exist
"""

from vectoradjust import _compat
from vectoradjust import errors as _errors
from vectoradjust.errors import VectorAdjustError  # noqa: F401 - the API's first name

__version__ = "0.3.0"

#: the error classes (loaded with the package anyway): every user error, and a cancel;
#: not their common base MessageError (catch VectorAdjustError or CancelledError)
_ERRORS = [name for name in _errors.__all__ if name != "MessageError"]
globals().update({name: getattr(_errors, name) for name in _ERRORS})

#: the other public names, imported when first used, by the module that holds them
_LAZY = {
    **{name: "vectoradjust.runner.project_run"
       for name in ("read_project", "run_project", "RunOptions", "ProjectResult", "Project",
                    "sample_project_dir")},
    "AdjustmentRun": "vectoradjust.results",
    "ProjectData": "vectoradjust.model",
}

__all__ = ["__version__", *_ERRORS, *_LAZY]


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'vectoradjust' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # once
    return value


def __dir__() -> list:
    return sorted(set(globals()) | set(_LAZY))


_compat.install()

"""Simulated projects with known truth (the sample project, tests, validation).

:func:`make_scenario` builds a stereo pair or block, GCPs, road databases with
database, identification and image errors; :func:`write_project` writes it in the file
contract; ``python -m vectoradjust.simulate OUT_DIR`` does both from the command line.

Modules: :mod:`.scenario` (:func:`make_scenario` and the command line),
:mod:`.geometry` (set-up, terrain, DEM, random streams), :mod:`.roads` (true roads and
road databases), :mod:`.real_roads` (real road geometry as the true roads),
:mod:`.imaging` (orientation, image measurements, effects, scanning), :mod:`.container`
(:class:`Scenario`), :mod:`.writer` (:func:`write_project`), :mod:`.readme`
(:func:`describe`), :mod:`.conflation` (a database with a smooth error field, partly
measured: the conflation's test scenarios), :mod:`.physics` (an independent formulation
of the frame camera, the simulator's truth), :mod:`.render` and :mod:`.measure_scene`
(rendered stereo images with painted roads, for :mod:`vectoradjust.measure`),
:mod:`.drone` (a drone block over real roads), :mod:`.satellite`,
:mod:`.satellite_project` and :mod:`.satellite_sample` (pushbroom images with RPCs, the
satellite block and sample) and ``__main__`` (``python -m vectoradjust.simulate``).
"""

from vectoradjust.simulate.container import Scenario
from vectoradjust.simulate.geometry import terrain_height
from vectoradjust.simulate.imaging import EFFECTS
from vectoradjust.simulate.readme import describe
from vectoradjust.simulate.real_roads import RoadLines, read_road_lines
from vectoradjust.simulate.roads import DATABASES, DatabaseModel
from vectoradjust.simulate.scenario import main, make_scenario
from vectoradjust.simulate.writer import write_project

__all__ = ["DatabaseModel", "DATABASES", "EFFECTS", "Scenario", "make_scenario",
           "terrain_height", "write_project", "describe", "main", "RoadLines",
           "read_road_lines"]

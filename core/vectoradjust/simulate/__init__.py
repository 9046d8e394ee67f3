"""Simulated projects with known truth (the sample project, tests, validation).

:func:`make_scenario` builds a stereo pair or block, GCPs, road databases with
database, identification and image errors; :func:`write_project` writes it in the file
contract; ``python -m vectoradjust.simulate OUT_DIR`` does both from the command line.
"""

from vectoradjust.simulate.scenario import (
    DATABASES,
    EFFECTS,
    DatabaseModel,
    Scenario,
    describe,
    main,
    make_scenario,
    terrain_height,
    write_project,
)

__all__ = ["DatabaseModel", "DATABASES", "EFFECTS", "Scenario", "make_scenario",
           "terrain_height", "write_project", "describe", "main"]

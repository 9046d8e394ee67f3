"""Headless reference numbers for the QGIS plugin tests (run by the venv's Python).

Uses the headless readers (geopandas, rasterio) and shapely, which must never be
loaded into QGIS, so the tests call this script in a subprocess::

    python headless_reference.py extract OUT.json LAYER ID_FIELD|- DEM|- CRS TOLERANCE
    python headless_reference.py buffer OUT.json TESTED REFERENCE WIDTH,WIDTH,... [METHOD]

(``METHOD``: ``exact``, the default, as the plugin's round buffers, or ``polygon``.)
"""

import json
import sys

import numpy as np


def extract(out, layer, id_field, dem, crs, tolerance):
    from vectoradjust.adjust.shapepoints import extract_shape_points
    from vectoradjust.files.readers import check_projected_crs, read_line_layer, sample_dem

    target = check_projected_crs(crs, "reference")
    lyr = read_line_layer(layer, "ref", None if id_field == "-" else id_field, target)
    if dem != "-":
        lyr.coords[:, 2] = sample_dem(dem, lyr.coords[:, :2], target)
    sp = extract_shape_points(lyr, float(tolerance))
    result = {
        "vertex_ids": sp.vertex_ids.tolist(),
        "feature_ids": lyr.feature_ids[lyr.vertex_feature].tolist(),
        "vertex_index": lyr.vertex_index.tolist(),
        "vertex_part": lyr.vertex_part.tolist(),
        "coords": [[None if not np.isfinite(v) else float(v) for v in row]
                   for row in lyr.coords],
        "object_ids": sp.object_ids[sp.vertex_object].tolist(),
        "problems": {str(k): v for k, v in lyr.problems.items()},
    }
    with open(out, "w", encoding="utf-8") as fh:
        json.dump(result, fh)


def buffer(out, tested, reference, widths, method="exact"):
    import geopandas as gpd

    from vectoradjust.accuracy.buffer import buffer_test

    t = gpd.read_file(tested)
    r = gpd.read_file(reference)
    if r.crs is not None and t.crs is not None and not r.crs.equals(t.crs):
        r = r.to_crs(t.crs)
    w = [float(x) for x in widths.split(",")]
    with open(out, "w", encoding="utf-8") as fh:
        json.dump(buffer_test(t.geometry.to_numpy(), r.geometry.to_numpy(), w, method=method),
                  fh)


if __name__ == "__main__":
    mode, *args = sys.argv[1:]
    {"extract": extract, "buffer": buffer}[mode](*args)

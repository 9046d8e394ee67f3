"""Write the sample project's OSM-like roads as an OpenStreetMap PBF (test fixture).

Run once by hand (needs osmium-tool: ``apt-get install osmium-tool``):

    python tests/data/osm/make_sample_pbf.py

The ways get the sample's ``osm_id`` values as way ids and keep their vertex order, so
shape point ids ``<osm_id>_<vertex>`` are the same as in ``osm_roads.shp``. The data are
simulated (vectoradjust.simulate), not OpenStreetMap data.
"""

import subprocess
from pathlib import Path
from xml.sax.saxutils import quoteattr

import geopandas as gpd

HERE = Path(__file__).resolve().parent
SAMPLE = HERE.parents[2] / "resources" / "sample"


def main() -> None:
    g = gpd.read_file(SAMPLE / "osm_roads.shp").to_crs(4326)
    g = g[g.geometry.geom_type == "LineString"]  # OSM ways are single lines
    nodes, ways = [], []
    node_id = 1
    for _, row in g.iterrows():
        refs = []
        for lon, lat in row.geometry.coords:
            nodes.append(f'  <node id="{node_id}" version="1" lat="{lat:.9f}" lon="{lon:.9f}"/>')
            refs.append(node_id)
            node_id += 1
        tags = [f'    <tag k="highway" v={quoteattr(str(row["highway"]))}/>']
        if row.get("name"):
            tags.append(f'    <tag k="name" v={quoteattr(str(row["name"]))}/>')
        nds = "\n".join(f'    <nd ref="{r}"/>' for r in refs)
        ways.append(f'  <way id="{int(row["osm_id"])}" version="1">\n{nds}\n'
                    + "\n".join(tags) + "\n  </way>")
    xml = ('<?xml version="1.0" encoding="UTF-8"?>\n<osm version="0.6" generator="vectoradjust">\n'
           + "\n".join(nodes) + "\n" + "\n".join(ways) + "\n</osm>\n")
    (HERE / "sample_roads.osm").write_text(xml)
    subprocess.run(["osmium", "cat", "--overwrite", str(HERE / "sample_roads.osm"), "-o",
                    str(HERE / "sample_roads.osm.pbf")], check=True)
    (HERE / "sample_roads.osm").unlink()


if __name__ == "__main__":
    main()

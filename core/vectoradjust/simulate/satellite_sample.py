"""The satellite sample: the frame sample's ground seen by a simulated pushbroom triplet.

:func:`write_satellite_sample` takes the true points of the frame sample
(``resources/sample``: control, check and tie points in ``truth_points.csv``, the road
databases' true vertices in ``truth_*.csv``), images them with a simulated along-track
stereo triplet (:func:`vectoradjust.simulate.satellite.satellite_scenario`: a rigorous
pushbroom model, RPCs fitted to it "as the vendor delivered them", a known image-space
bias per image, Gaussian pixel noise) and writes a project that reuses the sample's road
layers, DEM, control and truth beside its own RPC side files and pixel measurements.

Every number is simulated. The sample's heights are taken as ellipsoidal (``heights =
"ellipsoidal"``), so no geoid grid is needed.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

__all__ = ["write_satellite_sample", "SAMPLE_CRS"]

#: the frame sample's CRS (UTM zone 16N)
SAMPLE_CRS = "EPSG:32616"

_PROJECT = """# Satellite sample written by vectoradjust.simulate.satellite_sample (seed {seed});
# every number is simulated: the frame sample's ground (..) seen by a pushbroom triplet.
name = "vectoradjust simulated satellite triplet, seed {seed}"
crs = "{crs}"
heights = "ellipsoidal"         # the RPCs' heights; the sample's heights are taken as such

{images}
[measurements]
path = "image_points.csv"
unit = "pixel"                  # column, row; 0 at the corner of the first pixel

[control]
path = "../gcps.csv"

[[vectors]]
name = "OSM"
path = "../osm_roads.shp"
id_field = "osm_id"
sigma = [10.0, 10.0, 0.15]
dem = "../dem.tif"
truth = "../truth_osm.csv"
identification_sigma = [0.5, 0.0]

[adjustment]
max_iterations = 20
reweight = "two-pass"
alpha = 0.05

[truth]
path = "../truth_roads.shp"
widths = [1.0, 2.0]
"""

_IMAGE = """[[images]]
id = "{id}"
model = "rpc"
rpc = "{id}_rpc.txt"
bias = "shift"                  # a near-constant image-space shift (Grodecki and Dial 2003)
"""


def _true_points(sample: Path):
    """Ids, kinds and true X, Y, Z of the sample's points that are measured."""
    ids, kind, xyz = [], [], []
    with open(sample / "truth_points.csv", newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            ids.append(row["point_id"])
            kind.append({"control": "control", "check": "check"}.get(row["role"], "tie"))
            xyz.append([float(row["X"]), float(row["Y"]), float(row["Z"])])
    with open(sample / "truth_osm.csv", newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            ids.append(row["point_id"])
            kind.append("road")
            xyz.append([float(row["X"]), float(row["Y"]), float(row["Z"])])
    return np.array(ids), np.array(kind), np.array(xyz)


def write_satellite_sample(folder, sample=None, seed: int = 27, sigma_px: float = 0.3,
                           identification_m: float = 0.5):
    """Write the satellite sample project into ``folder`` (a subfolder of the sample).

    Parameters
    ----------
    folder : path
        Where ``project.toml``, ``image_points.csv``, ``S1_rpc.txt`` ... are written; the
        project refers to the frame sample's files as ``../``.
    sample : path, optional
        The frame sample (default ``folder``'s parent).
    seed : int
    sigma_px : float
        Pixel noise of every measurement.
    identification_m : float
        Horizontal identification error (m) added to the road vertices before imaging
        (the analyst measures a point near the real vertex, as in the frame sample).

    Returns
    -------
    SatelliteScenario
        The simulation (true bias, RPC fit, observations).
    """
    from pyproj import Transformer

    from vectoradjust.files.rpc import write_rpc
    from vectoradjust.simulate.satellite import GroundPoints, satellite_scenario

    folder = Path(folder)
    sample = Path(sample) if sample is not None else folder.parent
    folder.mkdir(parents=True, exist_ok=True)
    ids, kind, xyz = _true_points(sample)
    rng = np.random.default_rng(seed)
    road = kind == "road"
    xyz = xyz.copy()
    # one identification error per road point: vertices of several features at one
    # junction (one object point once merged) share it
    _, place = np.unique(np.round(xyz[road, :2], 3), axis=0, return_inverse=True)
    place = np.asarray(place).reshape(-1)
    xyz[road, :2] += rng.normal(0.0, identification_m, (int(place.max()) + 1, 2))[place]
    lon, lat = Transformer.from_crs(SAMPLE_CRS, "EPSG:4326", always_xy=True).transform(
        xyz[:, 0], xyz[:, 1])
    sc = satellite_scenario(3, "shift", 6.0, seed, GroundPoints(ids, lon, lat, xyz[:, 2], kind),
                            sigma_px=sigma_px, image_size=(4000, 4000))
    names = [f"S{i + 1}" for i in range(sc.n_images)]
    for name, rpc in zip(names, sc.rpcs):
        write_rpc(rpc, folder / f"{name}_rpc.txt")
    with open(folder / "image_points.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["point_id", "image_id", "x", "y", "sigma_x", "sigma_y"])
        for p, i, c, r, s in zip(sc.obs_point, sc.obs_image, sc.obs_col, sc.obs_row,
                                 sc.obs_sigma):
            w.writerow([ids[p], names[i], f"{c:.4f}", f"{r:.4f}", f"{s:.3f}", f"{s:.3f}"])
    with open(folder / "truth_bias.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["image_id", "a0", "a1", "a2", "b0", "b1", "b2", "rpc_fit_max_px"])
        for name, b, fit in zip(names, sc.true_bias, sc.fit_max_px):
            w.writerow([name, *(f"{v:.4f}" for v in b), f"{fit:.2e}"])
    images = "\n".join(_IMAGE.format(id=n) for n in names)
    (folder / "project.toml").write_text(
        _PROJECT.format(seed=seed, crs=SAMPLE_CRS, images=images), encoding="utf-8")
    return sc

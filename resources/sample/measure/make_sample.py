"""Write the small-image measurement sample (``resources/sample/measure/``), seeded.

Three 400 x 400 pixel images of a digital frame camera (50 mm, 0.06 mm pixels, a few
pixels of lens distortion; :func:`vectoradjust.simulate.render.camera`) flown in an
east-west strip 300 m above a textured ground with painted roads
(:func:`vectoradjust.simulate.render.make_scene`, matplotlib's public-domain
``grace_hopper.jpg`` tiled with fractal noise), rendered with the TRUE orientation
through the package's own sensor model (:func:`vectoradjust.simulate.render.render`:
every pixel traced to the terrain) and stored as JPEG (quality 75). The project gives
an approximate orientation (true + N(0, 0.5 m), N(0, 0.02 deg)) with those sigmas.

Files: ``L.jpg M.jpg R.jpg`` (images), ``project.toml``, ``gcps.csv`` (surveyed control
points: true + N(0, 0.05 / 0.05 / 0.08 m)), ``measured_L.csv`` (the control points
measured on image L: their true pixels + N(0, 0.2 px), as an analyst would), ``roads.shp``
(the painted centrelines, shifted 1.5 m east and 1 m south as a database would be),
``dem.tif`` (5 m cells of the true terrain), ``truth_eo.csv`` and ``truth_pixels.csv``
(the true pixel of every control point on every image it falls on).

Run from the repository: ``python resources/sample/measure/make_sample.py [OUT_DIR]``
(default: this folder). Reproducible: the same seed writes the same numbers; the JPEG
bytes depend on GDAL's libjpeg.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np

SEED = 28
SIZE = 400  # pixels
HEIGHT = 300.0  # m above the terrain's mean
BASE = 45.0  # m between neighbouring images
SIGMA_POSITION, SIGMA_ATTITUDE = 0.5, 0.02  # m, degrees (the project's a-priori sigmas)
QUALITY = 75  # JPEG
N_CONTROL = 18


def scene_and_geometries(seed: int = SEED):
    """The scene, the camera and the true and approximate geometries of L, M, R."""
    from vectoradjust.measure.geometry import ImageGeometry
    from vectoradjust.simulate.render import camera, make_scene

    origin = np.array([500000.0, 4400000.0])
    c = origin + [150.0, -150.0]
    xs, ys = c[0] + np.array([-40.0, 35.0]), c[1] + np.array([-45.0, 30.0])
    roads = [np.array([[x + 2.0, c[1] - 140], [x - 2.0, c[1] + 140]]) for x in xs]
    roads += [np.array([[c[0] - 140, y - 1.5], [c[0] + 140, y + 1.5]]) for y in ys]
    scene = make_scene(300.0, 0.25, seed, "hopper", roads, origin)
    cam = camera(SIZE, pixel_size=0.06, focal_length=50.0, distortion=True)
    rng = np.random.default_rng(seed)
    sig = np.r_[np.full(3, SIGMA_POSITION), np.radians(np.full(3, SIGMA_ATTITUDE))]
    true, approx = {}, {}
    for k, iid in enumerate("LMR"):
        eo = np.r_[c[0] + (k - 1) * BASE, c[1] + 2.0 * k, scene.z0 + HEIGHT,
                   np.radians(rng.normal(0, 1.0, 3))]
        true[iid] = ImageGeometry(iid, eo, cam)
        approx[iid] = ImageGeometry(iid, eo + rng.normal(0, 1, 6) * sig, cam, sigma_eo=sig)
    return scene, cam, true, approx, c, rng


def write_images(folder: Path, scene, true: dict, seed: int = SEED) -> None:
    """Render each image with its own radiometry and noise and store it as JPEG."""
    import rasterio
    import rasterio.errors
    import rasterio.shutil
    from rasterio.io import MemoryFile

    from vectoradjust.simulate.render import render

    radiometry = {"L": (1.0, 0.0, 1.0, 2.0), "M": (0.9, 0.05, 1.1, 2.5),
                  "R": (0.8, 0.1, 1.25, 3.0)}
    for k, (iid, g) in enumerate(true.items()):
        img = render(scene, g, *radiometry[iid], seed=seed + k, supersample=2)
        with warnings.catch_warnings(), MemoryFile() as mf:
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            with mf.open(driver="GTiff", width=SIZE, height=SIZE, count=1,
                         dtype="uint8") as ds:
                ds.write(img, 1)
            with mf.open() as src:
                rasterio.shutil.copy(src, folder / f"{iid}.jpg", driver="JPEG",
                                     QUALITY=str(QUALITY))
        for side in folder.glob(f"{iid}.jpg.aux.xml"):
            side.unlink()


def write_geodata(folder: Path, scene, c) -> None:
    """The DEM (5 m, the true terrain) and the roads (shifted as a database would be)."""
    import geopandas as gpd
    import rasterio
    from rasterio.transform import Affine
    from shapely.geometry import LineString

    o = scene.origin
    n = 60
    xs, ys = o[0] + 2.5 + 5.0 * np.arange(n), o[1] - 2.5 - 5.0 * np.arange(n)
    gx, gy = np.meshgrid(xs, ys)
    z = scene.height(np.c_[gx.ravel(), gy.ravel()]).reshape(gx.shape).astype("float32")
    with rasterio.open(folder / "dem.tif", "w", driver="GTiff", width=n, height=n, count=1,
                       dtype="float32", crs="EPSG:32616", compress="deflate",
                       transform=Affine(5.0, 0.0, o[0], 0.0, -5.0, o[1])) as ds:
        ds.write(z, 1)
    lines = [LineString(_with_crossings(r, scene.roads) + np.array([1.5, -1.0]))
             for r in scene.roads]
    gpd.GeoDataFrame({"rid": np.arange(len(lines))}, geometry=lines,
                     crs="EPSG:32616").to_file(folder / "roads.shp")


def _with_crossings(road: np.ndarray, roads: list) -> np.ndarray:
    """A straight road's end points with its crossings of the other roads between them
    (shared vertices: junctions ``measure predict --roads`` can locate)."""
    p, d = road[0], road[1] - road[0]
    ts = [0.0, 1.0]
    for other in roads:
        q, e = other[0], other[1] - other[0]
        den = d[0] * e[1] - d[1] * e[0]
        if abs(den) < 1e-9:
            continue
        t = ((q - p)[0] * e[1] - (q - p)[1] * e[0]) / den
        u = ((q - p)[0] * d[1] - (q - p)[1] * d[0]) / den
        if 0 < t < 1 and 0 <= u <= 1:
            ts.append(t)
    return p + np.sort(ts)[:, None] * d


def write_points(folder: Path, scene, true: dict, c, rng) -> None:
    """Control points, the analyst's measurements on L and the true pixels."""
    xy = np.c_[rng.uniform(c[0] - 62, c[0] + 18, N_CONTROL),
               rng.uniform(c[1] - 58, c[1] + 58, N_CONTROL)]
    xyz = np.c_[xy, scene.height(xy)]
    survey = xyz + rng.normal(0, 1, xyz.shape) * [0.05, 0.05, 0.08]
    with open(folder / "gcps.csv", "w", encoding="utf-8", newline="\n") as fh:
        fh.write("point_id,X,Y,Z,sigma_x,sigma_y,sigma_z,role\n")
        for i, p in enumerate(survey):
            fh.write(f"G{i:02d},{p[0]:.3f},{p[1]:.3f},{p[2]:.3f},0.05,0.05,0.08,control\n")
    with open(folder / "truth_pixels.csv", "w", encoding="utf-8", newline="\n") as fh:
        fh.write("point_id,image_id,col,row\n")
        for iid, g in true.items():
            for i, p in enumerate(g.to_pixel(xyz)):
                if 20 <= p[0] <= SIZE - 21 and 20 <= p[1] <= SIZE - 21:
                    fh.write(f"G{i:02d},{iid},{p[0]:.3f},{p[1]:.3f}\n")
    meas = true["L"].to_pixel(xyz) + rng.normal(0, 0.2, (len(xyz), 2))
    with open(folder / "measured_L.csv", "w", encoding="utf-8", newline="\n") as fh:
        fh.write("point_id,image_id,col,row\n")
        for i, p in enumerate(meas):
            if 20 <= p[0] <= SIZE - 21 and 20 <= p[1] <= SIZE - 21:
                fh.write(f"G{i:02d},L,{p[0]:.2f},{p[1]:.2f}\n")
    with open(folder / "truth_eo.csv", "w", encoding="utf-8", newline="\n") as fh:
        fh.write("image_id,XL,YL,ZL,omega,phi,kappa\n")
        for iid, g in true.items():
            a = np.degrees(g.eo[3:])
            fh.write(f"{iid},{g.eo[0]:.4f},{g.eo[1]:.4f},{g.eo[2]:.4f},"
                     f"{a[0]:.6f},{a[1]:.6f},{a[2]:.6f}\n")


def write_project(folder: Path, cam, approx: dict) -> None:
    """``project.toml``: the camera, the approximate orientation and the inputs."""
    dist = ", ".join(f"{k} = {float(v)!r}" for k, v in cam.distortion_coefficients.items())
    imgs = ""
    for iid, g in approx.items():
        pos = ", ".join(f"{v:.3f}" for v in g.eo[:3])
        att = ", ".join(f"{v:.4f}" for v in np.degrees(g.eo[3:]))
        imgs += (f'[[images]]\nid = "{iid}"\npath = "{iid}.jpg"\nposition = [{pos}]\n'
                 f"attitude = [{att}]\nsigma_position = {SIGMA_POSITION}\n"
                 f"sigma_attitude = {SIGMA_ATTITUDE}\n\n")
    text = (f"# Small-image measurement sample written by make_sample.py (seed {SEED});"
            " see README.md\n"
            'name = "vectoradjust measurement sample"\ncrs = "EPSG:32616"\n\n'
            "[camera]  # a digital frame camera (SIMULATED)\n"
            f"focal_length = {cam.focal_length}\n"
            f"principal_point = [{cam.principal_point[0]}, {cam.principal_point[1]}]\n"
            f"pixel_size = {cam.pixel_size[0]}\n"
            f"image_size = [{cam.image_size[0]}, {cam.image_size[1]}]\n"
            f'distortion = {{ model = "smac", {dist} }}\n\n{imgs}'
            '[measurements]\npath = "out/image_points.csv"  # written by measure transfer\n\n'
            '[control]\npath = "gcps.csv"\n\n'
            '[[vectors]]\nname = "roads"\npath = "roads.shp"\nid_field = "rid"\n'
            'sigma = [3.0, 3.0, 3.0]\ndem = "dem.tif"\n')
    (folder / "project.toml").write_text(text, encoding="utf-8")


def main(folder: Path) -> None:
    """Write the whole sample into ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    scene, cam, true, approx, c, rng = scene_and_geometries()
    write_points(folder, scene, true, c, rng)
    write_geodata(folder, scene, c)
    write_images(folder, scene, true)
    write_project(folder, cam, approx)


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent)

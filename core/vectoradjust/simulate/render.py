"""Rendered stereo images of a textured ground with painted roads (known truth).

For tests and the validation of :mod:`vectoradjust.measure`: every output pixel is
traced back to the ground (pixel -> refined photo coordinates, i.e. lens distortion
removed -> ray -> intersection with the terrain by iteration) and takes the albedo
there, so the images obey the collinearity equations and the camera model exactly and
the true pixel of any ground point is :meth:`ImageGeometry.to_pixel` of the true
orientation. Albedo: a real photograph (matplotlib's sample image ``grace_hopper.jpg``,
a U.S. Navy photograph in the public domain) mirrored and tiled over the ground and
fractal noise, with roads painted on it; each image gets its own radiometry (gain,
offset, gamma) and noise.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

import numpy as np
from scipy.ndimage import gaussian_filter, map_coordinates, zoom

from vectoradjust.measure.geometry import ImageGeometry
from vectoradjust.sensor.camera import CameraCalibration

__all__ = ["Scene", "make_scene", "render", "hopper_texture", "fractal_noise"]


def hopper_path() -> Optional[Path]:
    """matplotlib's ``grace_hopper.jpg`` (public domain), if matplotlib is installed."""
    spec = importlib.util.find_spec("matplotlib")
    if spec is None or not spec.submodule_search_locations:
        return None
    p = Path(list(spec.submodule_search_locations)[0]) / "mpl-data" / "sample_data" / \
        "grace_hopper.jpg"
    return p if p.is_file() else None


def hopper_texture() -> Optional[np.ndarray]:
    """The sample photograph as grey values in [0, 1] (None when unavailable)."""
    p = hopper_path()
    if p is None:
        return None
    import warnings

    import rasterio

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a JPEG has no georeferencing
        with rasterio.open(p) as ds:
            a = ds.read().astype(float)
    return a.mean(axis=0) / 255.0


def fractal_noise(shape: tuple[int, int], seed: int, octaves: int = 6) -> np.ndarray:
    """Sum of smoothed noise octaves (1/f-like), normalised to [0, 1]."""
    rng = np.random.default_rng(seed)
    out = np.zeros(shape)
    for o in range(octaves):
        f = 2 ** max(o - 1, 0)  # coarse octaves are drawn on a coarser grid and zoomed
        small = (-(-shape[0] // f), -(-shape[1] // f))
        layer = gaussian_filter(rng.normal(size=small), 2.0 ** o * 0.7 / f, mode="wrap")
        if f > 1:
            layer = zoom(layer, f, order=1, mode="grid-wrap", grid_mode=True)[:shape[0], :shape[1]]
        out += layer / max(layer.std(), 1e-12) * 2.0 ** (-0.4 * o)
    out -= out.min()
    return out / max(out.max(), 1e-12)


def _segment_distance(xy: np.ndarray, lines: list) -> np.ndarray:
    """Distance of every point to the nearest of the polylines."""
    d2 = np.full(len(xy), np.inf)
    x, y = xy[:, 0], xy[:, 1]
    for line in lines:
        for (ax, ay), (bx, by) in zip(line[:-1], line[1:]):  # segments, not points
            ux, uy = bx - ax, by - ay
            t = np.clip(((x - ax) * ux + (y - ay) * uy) / max(ux * ux + uy * uy, 1e-12),
                        0.0, 1.0)
            d2 = np.minimum(d2, (x - ax - t * ux) ** 2 + (y - ay - t * uy) ** 2)
    return np.sqrt(d2)


@dataclass
class Scene:
    """A textured ground with roads.

    Attributes
    ----------
    origin : numpy.ndarray, shape (2,)
        Ground X, Y of the albedo grid's pixel (0, 0) centre.
    cell : float
        Albedo grid spacing (m).
    albedo : numpy.ndarray
        Grey values in [0, 1], rows north to south.
    roads : list of numpy.ndarray (k, 2)
        Road centrelines (X, Y).
    road_width : float
        Painted width (m).
    z0, relief : float
        Terrain ``z0 + relief * (sin + cos undulation)``.
    edge : float
        Width (m) of the linear ramp at a road's edge (anti-aliasing).
    """

    origin: np.ndarray
    cell: float
    albedo: np.ndarray
    roads: list = field(default_factory=list)
    road_width: float = 6.0
    z0: float = 200.0
    relief: float = 8.0
    edge: float = 0.15

    def height(self, xy: np.ndarray) -> np.ndarray:
        """Terrain height (m) at ``xy (n, 2)``."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        u = (xy - self.origin) / 100.0
        return self.z0 + self.relief * (np.sin(0.9 * u[:, 0]) * np.cos(0.7 * u[:, 1])
                                        + 0.3 * np.sin(2.1 * u[:, 1] + 0.4))

    def value(self, xy: np.ndarray) -> np.ndarray:
        """Albedo at ground ``xy`` (bilinear), roads painted on it."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        col = (xy[:, 0] - self.origin[0]) / self.cell
        row = (self.origin[1] - xy[:, 1]) / self.cell
        v = map_coordinates(self.albedo, [row, col], order=1, mode="mirror")
        if self.roads:
            d = _segment_distance(xy, self.roads)
            edge = np.clip((self.road_width / 2.0 - d) / self.edge + 0.5, 0.0, 1.0)
            road = 0.85 + 0.05 * (v - 0.5)
            v = v * (1.0 - edge) + road * edge
        return v


def make_scene(extent: float = 500.0, cell: float = 0.25, seed: int = 0,
               texture: str = "hopper", roads: Optional[list] = None,
               origin=(500000.0, 4400000.0)) -> Scene:
    """A square ground of ``extent`` m with the chosen texture (hopper or fractal)."""
    n = int(extent / cell)
    noise = fractal_noise((n, n), seed)
    tex = hopper_texture() if texture == "hopper" else None
    if tex is not None:
        reps = (int(np.ceil(n / tex.shape[0])) + 1, int(np.ceil(n / tex.shape[1])) + 1)
        big = np.block([[tex[:: (1 if i % 2 == 0 else -1), :: (1 if j % 2 == 0 else -1)]
                         for j in range(reps[1])] for i in range(reps[0])])[:n, :n]
        albedo = 0.7 * big + 0.3 * noise
    else:
        albedo = noise
    return Scene(np.asarray(origin, float), cell, albedo, roads or [])


def render(scene: Scene, geom: ImageGeometry, gain: float = 1.0, offset: float = 0.0,
           gamma: float = 1.0, noise: float = 0.0, seed: int = 0, supersample: int = 2,
           rows_per_chunk: int = 64,
           progress: Optional[Callable[[float, str], None]] = None) -> np.ndarray:
    """Render one image (``uint8``, ``image_size`` of the camera).

    Each pixel averages ``supersample^2`` rays; grey value
    ``255 (gain albedo^gamma + offset) + noise``, clipped to 0..255.
    """
    cols, rows = geom.camera.image_size
    out = np.empty((rows, cols))
    sub = (np.arange(supersample) + 0.5) / supersample - 0.5
    su, sv = np.meshgrid(sub, sub)
    for r0 in range(0, rows, rows_per_chunk):
        r1 = min(rows, r0 + rows_per_chunk)
        rr, cc = np.mgrid[r0:r1, 0:cols]
        px = np.stack([cc[..., None] + su.ravel(), rr[..., None] + sv.ravel()], axis=-1)
        g = geom.to_ground(px.reshape(-1, 2), scene.height)
        val = scene.value(g[:, :2]).reshape(r1 - r0, cols, -1).mean(axis=-1)
        out[r0:r1] = val
        if progress is not None:
            progress(r1 / rows, f"rendering {geom.image_id}")
    rng = np.random.default_rng(seed)
    img = 255.0 * (gain * np.clip(out, 0, 1) ** gamma + offset) + rng.normal(0, noise, out.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def camera(image_size: int = 1500, pixel_size: float = 0.04, focal_length: float = 50.0,
           distortion: bool = True) -> CameraCalibration:
    """A digital frame camera with (optionally) a few pixels of lens distortion."""
    dist = {"K1": -1.6e-6 * (0.04 / pixel_size) ** 0, "P1": 2e-6} if distortion else {}
    return CameraCalibration(focal_length=focal_length, principal_point=(0.02, -0.015),
                             pixel_size=(pixel_size, pixel_size),
                             image_size=(image_size, image_size),
                             distortion_model="smac" if distortion else "none",
                             distortion_coefficients=dist)

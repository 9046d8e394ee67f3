"""A rendered stereo pair with known truth for :mod:`vectoradjust.measure` (tests, validation).

:func:`stereo_pair` builds a textured ground with a grid of painted roads, a digital
frame camera with lens distortion, the true and an approximate exterior orientation
(errors drawn with the stated sigmas) and renders both images with different
radiometry and noise; :class:`ArrayImage` reads windows of an image held in memory.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vectoradjust.measure.geometry import ImageGeometry
from vectoradjust.measure.ties import ArrayReader
from vectoradjust.simulate.render import Scene, camera, make_scene, render

__all__ = ["ArrayImage", "StereoPair", "stereo_pair"]


#: a reader (``size``, ``read``) over an image array (NaN outside): the measuring
#: module's own (:class:`vectoradjust.measure.ties.ArrayReader`)
ArrayImage = ArrayReader


@dataclass
class StereoPair:
    """Truth and approximations of a rendered pair."""

    scene: Scene
    true: dict
    approx: dict
    images: dict
    junctions: np.ndarray


def stereo_pair(size: int = 1000, seed: int = 1, texture: str = "hopper",
                sigma_position: float = 0.3, sigma_attitude: float = 0.01,
                supersample: int = 2, distortion: bool = True) -> StereoPair:
    """Render a stereo pair (60 % overlap) over a road grid; errors with the given sigmas.

    ``supersample = 2`` averages 2 x 2 rays per pixel (a pixel integrates light over its
    area); with 1 ray per pixel the aliasing of fine texture and road edges differs
    between the two images and costs matching accuracy (a few matches off by 0.5 px).
    """
    cam = camera(size, pixel_size=0.06 * 1000 / size, focal_length=50.0, distortion=distortion)
    origin = np.array([500000.0, 4400000.0])
    c = origin + [250.0, -250.0]
    xs = c[0] + np.array([-90.0, 0.0, 85.0])
    ys = c[1] + np.array([-70.0, 5.0, 80.0])
    roads = [np.array([[x + 3.0, c[1] - 200], [x - 3.0, c[1] + 200]]) for x in xs]
    roads += [np.array([[c[0] - 200, y - 2.0], [c[0] + 200, y + 2.0]]) for y in ys]
    scene = make_scene(500.0, 0.25, seed, texture, roads, origin)
    junctions = _crossings(roads)
    junctions = np.column_stack([junctions, scene.height(junctions)])
    rng = np.random.default_rng(seed)
    sig = np.r_[np.full(3, sigma_position), np.radians(np.full(3, sigma_attitude))]
    true, approx, images = {}, {}, {}
    radiometry = {"L": (1.0, 0.0, 1.0, 2.0), "R": (0.8, 0.1, 1.25, 3.0)}
    for k, (iid, dx) in enumerate((("L", -60.0), ("R", 60.0))):
        eo = np.r_[c[0] + dx, c[1] + 3.0 * k, scene.z0 + 300.0,
                   np.radians(rng.normal(0, 1.0, 3))]
        true[iid] = ImageGeometry(iid, eo, cam)
        approx[iid] = ImageGeometry(iid, eo + rng.normal(0, 1, 6) * sig, cam, sigma_eo=sig)
        gain, off, gam, noise = radiometry[iid]
        images[iid] = render(scene, true[iid], gain, off, gam, noise, seed + k, supersample)
    return StereoPair(scene, true, approx, images, junctions)


def _crossings(roads: list) -> np.ndarray:
    """Intersections of every pair of the straight roads."""
    out = []
    for i in range(len(roads)):
        for j in range(i + 1, len(roads)):
            p, r = roads[i][0], roads[i][1] - roads[i][0]
            q, s = roads[j][0], roads[j][1] - roads[j][0]
            den = r[0] * s[1] - r[1] * s[0]
            if abs(den) < 1e-9:
                continue
            t = ((q - p)[0] * s[1] - (q - p)[1] * s[0]) / den
            u = ((q - p)[0] * r[1] - (q - p)[1] * r[0]) / den
            if 0 <= t <= 1 and 0 <= u <= 1:
                out.append(p + t * r)
    return np.array(out)

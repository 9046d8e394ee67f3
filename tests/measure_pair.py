"""One rendered stereo pair shared by the measurement tests (rendered once per session)."""

from __future__ import annotations

from functools import cache


@cache
def rendered_pair(seed: int = 1):
    """:func:`vectoradjust.simulate.measure_scene.stereo_pair` of 1000 x 1000 pixels."""
    from vectoradjust.simulate.measure_scene import stereo_pair

    return stereo_pair(1000, seed=seed, sigma_position=0.5, sigma_attitude=0.02)

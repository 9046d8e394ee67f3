"""The sensor seam: which model each image of an adjustment has.

An adjustment's images carry six parameters each. For a frame camera they are the
exterior orientation ``XL, YL, ZL, omega, phi, kappa`` (m, rad) of the collinearity
equations (:mod:`~vectoradjust.sensor.collinearity`); for a satellite image with rational
polynomial coefficients they are the image-space bias ``a0, a1, a2, b0, b1, b2`` (px) of
:mod:`~vectoradjust.sensor.rpc` (Grodecki and Dial 2003), of which the bias model
(``none``, ``shift``, ``shift+drift``, ``affine``) frees some and fixes the rest at zero.

A :class:`SensorSet` says, per image of a :class:`~vectoradjust.adjust.bundle.BundleProblem`,
which model it has; frame images need nothing more than the problem's camera. RPC images
need a :class:`~vectoradjust.sensor.ground.GroundFrame` that turns the adjustment's object
coordinates into the geodetic longitude, latitude and ellipsoidal height of the RPCs.

Imports numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from vectoradjust.errors import ProjectError

__all__ = [
    "BIAS_PARAMETERS",
    "EO_PARAMETERS",
    "RpcImage",
    "SensorSet",
    "bias_free_mask",
    "observe_rpc",
    "corrected_rpc_names",
]

#: names of the six bias parameters of an RPC image, in the parameter vector's order
BIAS_PARAMETERS = ("a0", "a1", "a2", "b0", "b1", "b2")
#: names of a frame image's exterior orientation parameters (summary.json ``correlation``)
EO_PARAMETERS = ("X", "Y", "Z", "omega", "phi", "kappa")


def bias_free_mask(model: str) -> np.ndarray:
    """Which of the six bias parameters the bias model estimates, ``(6,)`` bool.

    >>> bias_free_mask("shift").astype(int).tolist()
    [1, 0, 0, 1, 0, 0]
    """
    from vectoradjust.sensor.rpc import BIAS_MODELS

    if model not in BIAS_MODELS:
        raise ProjectError(f"unknown bias model {model!r}",
                           "Use one of " + ", ".join(repr(m) for m in BIAS_MODELS))
    free = np.zeros(6, bool)
    free[list(BIAS_MODELS[model])] = True
    return free


@dataclass
class RpcImage:
    """One satellite image with RPCs and its bias model.

    Attributes
    ----------
    rpc : vectoradjust.sensor.rpc.RpcModel
        The vendor's RPCs (unbiased, as delivered).
    bias : str
        ``"none"``, ``"shift"``, ``"shift+drift"`` or ``"affine"``.
    bias_sigma : numpy.ndarray, shape (6,)
        A-priori sigmas of ``a0, a1, a2, b0, b1, b2`` (px); ``inf`` for a parameter
        without prior. Parameters the bias model does not estimate are held at their
        approximate value (``BundleProblem.eo0``: zero, unless a caller starts elsewhere)
        whatever their sigma.
    path : str or None
        Where the RPCs were read from (messages, corrected RPCs written beside it).
    """

    rpc: Any
    bias: str = "shift"
    bias_sigma: np.ndarray = field(default_factory=lambda: np.full(6, np.inf))
    path: Optional[str] = None

    def __post_init__(self) -> None:
        self.bias_sigma = np.broadcast_to(np.asarray(self.bias_sigma, float), (6,)).copy()
        bias_free_mask(self.bias)  # validates the name

    @property
    def free(self) -> np.ndarray:
        """The estimated bias parameters, ``(6,)`` bool."""
        return bias_free_mask(self.bias)


@dataclass
class SensorSet:
    """The sensor model of every image of an adjustment.

    Attributes
    ----------
    rpc : list
        Per image: an :class:`RpcImage`, or None for a frame camera.
    frame : GroundFrame or None
        Object coordinates to geodetic (needed as soon as one image has RPCs).
    """

    rpc: list
    frame: Any = None

    def __post_init__(self) -> None:
        if self.rpc_images.size and self.frame is None:
            raise ProjectError("RPC images need a ground frame (object coordinates to "
                               "longitude, latitude and ellipsoidal height)",
                               "Give the project a projected crs")

    @property
    def rpc_images(self) -> np.ndarray:
        """Indices of the images with RPCs."""
        return np.array([i for i, r in enumerate(self.rpc) if r is not None], np.int64)

    @property
    def is_rpc(self) -> np.ndarray:
        """``(n,)`` bool: the image has RPCs."""
        return np.array([r is not None for r in self.rpc], bool)

    def subset(self, images) -> SensorSet:
        """The sensors of some images, in the given order."""
        return SensorSet([self.rpc[int(i)] for i in np.asarray(images).reshape(-1)], self.frame)

    def fixed(self) -> np.ndarray:
        """``(n, 6)`` bool: parameters held at their approximate value (RPC bias
        parameters that the image's bias model does not estimate)."""
        out = np.zeros((len(self.rpc), 6), bool)
        for i, r in enumerate(self.rpc):
            if r is not None:
                out[i] = ~r.free
        return out


def observe_rpc(image: RpcImage, params: np.ndarray, llh: np.ndarray, jac: np.ndarray):
    """Computed pixel position of ground points on an RPC image and its partials.

    Parameters
    ----------
    image : RpcImage
    params : numpy.ndarray, shape (6,)
        The current bias parameters (px).
    llh : numpy.ndarray, shape (g, 3)
        Longitude, latitude (deg), ellipsoidal height (m) of the points.
    jac : numpy.ndarray, shape (g, 3, 3)
        ``d(lon, lat, h) / d(X, Y, Z)`` of the ground frame.

    Returns
    -------
    colrow : numpy.ndarray, shape (g, 2)
        Column, row (px, GDAL's convention: 0 at the corner of the first pixel).
    d_params : numpy.ndarray, shape (g, 2, 6)
    d_xyz : numpy.ndarray, shape (g, 2, 3)
    """
    from vectoradjust.sensor.rpc import biased_partials

    colrow, d_ground, d_params = biased_partials(image.rpc, llh[:, 0], llh[:, 1], llh[:, 2],
                                                 np.asarray(params, float))
    # matmul, not einsum: 3.4x faster on these (g, 2, 3) @ (g, 3, 3) stacks (numpy 2.x;
    # benchmarks/bench_rpc_block.py)
    return colrow, d_params, np.matmul(d_ground, jac)


def corrected_rpc_names(images: list) -> dict:
    """File names of the corrected RPCs of a project's RPC images, by image id.

    An image whose RPCs came from ``img_01.tif`` (or ``img_01_rpc.txt``, ``img_01.RPB``)
    gets ``img_01_rpc.txt``, the side file GDAL reads for ``img_01.tif``; two images with
    RPC files of one name get their id added.

    Parameters
    ----------
    images : list of vectoradjust.model.ImageSpec

    Returns
    -------
    dict of str to str
    """
    names: dict = {}
    for im in images:
        if im.model != "rpc":
            continue
        base = str(im.rpc.path or im.id).replace("\\", "/").rsplit("/", 1)[-1]
        stem = base.rsplit(".", 1)[0] if "." in base else base
        if stem.lower().endswith("_rpc"):
            stem = stem[:-4]
        name = f"{stem}_rpc.txt"
        if name in names.values():
            name = f"{stem}_{im.id}_rpc.txt"
        names[str(im.id)] = name
    return names

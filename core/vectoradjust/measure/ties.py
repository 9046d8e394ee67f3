"""Automatic tie points between frame images from an approximate orientation.

:func:`tie_points` measures tie points of a block of frame images whose exterior
orientation is known approximately (GNSS/INS, a previous adjustment):

1. *Candidates* on each image in turn (:func:`texture_points`): one per cell of a regular
   grid, the pixel with the largest Foerstner weight ``w = det(N) / trace(N)`` of the
   structure tensor ``N`` among those whose roundness ``q = 4 det(N) / trace(N)^2``
   passes a threshold (the texture check: corners and blobs, not edges or flat areas).
2. *Prediction* in every other image: the ray of the candidate is intersected with the
   terrain (a DEM's heights, :meth:`ImageGeometry.to_ground`) and the ground point
   projected into the other image (:func:`~vectoradjust.measure.geometry.local_affine`,
   which also gives the local affine between the images). The search window is the
   covariance of that transfer (:func:`~vectoradjust.measure.geometry.transfer_covariance`:
   both orientations' sigmas and the terrain height's sigma along the epipolar line).
3. *Matching* with :func:`vectoradjust.measure.transfer.match_batch` (NCC in the
   reference geometry, least-squares matching, its failure flags: correlation, LSM
   precision, ambiguity, window).
4. *Back-matching*: the matched pixel is predicted and matched back in the reference
   image the same way; the tie is kept only when that lands within ``back_tolerance``
   pixels of the candidate.

A candidate matched on at least one other image becomes one object point, observed on
its reference image and on every image where it was accepted. The result holds the
measurements table (point id, image, ``x, y`` in mm) that a bundle adjustment takes
(:class:`~vectoradjust.adjust.bundle.BundleProblem` with zero prior weight on the points).

Images are *readers* (``size`` = (columns, rows) and ``read(col0, row0, width, height)``
giving a float array, NaN outside the image) or 2-D arrays; this module reads no file.
Pixel coordinates are a frame camera's (array indices: the element ``[r, c]`` is centred
on ``(c, r)``, :attr:`ImageGeometry.index_offset` = 0).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Callable, Union

import numpy as np
from scipy.ndimage import uniform_filter

from vectoradjust.errors import MeasurementError
from vectoradjust.measure.geometry import ImageGeometry, local_affine, transfer_covariance
from vectoradjust.measure.matching import FLAGS
from vectoradjust.measure.transfer import MatchSettings, match_batch

__all__ = ["TIE_FLAGS", "TiePoints", "ArrayReader", "foerstner", "texture_points",
           "tie_settings", "tie_points"]

#: flags of a candidate on a target image (bits): those of
#: :data:`vectoradjust.measure.matching.FLAGS` for the forward match, and:
TIE_FLAGS = {
    **FLAGS,
    "back_mismatch": 256,   # back-matching failed or missed by more than the tolerance
    "off_image": 512,       # the prediction (or its window) falls outside the target
}

HeightLike = Union[float, Callable[[np.ndarray], np.ndarray]]
#: points matched together (a batch's chips and LSM temporaries stay a few MB)
_BATCH = 64


class ArrayReader:
    """A reader (``size``, ``read``) over a 2-D image array (NaN outside).

    Parameters
    ----------
    a : array_like, shape (rows, columns)
        Grey values.
    """

    def __init__(self, a) -> None:
        self.a = np.asarray(a, float)
        if self.a.ndim != 2:
            raise MeasurementError(
                f"an image array must have 2 dimensions (rows, columns), not {self.a.ndim}",
                "Give one band (e.g. the mean of the colour bands) as a 2-D array")
        self.size = (self.a.shape[1], self.a.shape[0])

    def read(self, col0: int, row0: int, width: int, height: int) -> np.ndarray:
        """The window whose top-left element is ``(col0, row0)``."""
        out = np.full((height, width), np.nan)
        c0, r0 = max(col0, 0), max(row0, 0)
        c1, r1 = min(col0 + width, self.size[0]), min(row0 + height, self.size[1])
        if c1 > c0 and r1 > r0:
            out[r0 - row0:r1 - row0, c0 - col0:c1 - col0] = self.a[r0:r1, c0:c1]
        return out


def _reader(image):
    """A reader from a reader or an array."""
    if hasattr(image, "read") and hasattr(image, "size"):
        return image
    return ArrayReader(image)


@dataclass
class TiePoints:
    """Tie points of a block: the measurements and how each pair fared.

    Attributes
    ----------
    point_id : numpy.ndarray of str, shape (k,)
        Object point of each measurement (``"<reference image>-<candidate>"``).
    image_id : numpy.ndarray of str, shape (k,)
    image : numpy.ndarray of int, shape (k,)
        Index of the image in the geometries given.
    px : numpy.ndarray, shape (k, 2)
        Column, row (the reference image's candidate or the matched pixel).
    xy : numpy.ndarray, shape (k, 2)
        Refined photo coordinates (mm; principal point reduced, lens distortion removed
        as the image's ``corrections`` say): the collinearity equations' ``x, y`` with
        principal point (0, 0).
    ncc, rho, back_error : numpy.ndarray, shape (k,)
        NCC and LSM correlation and back-matching error (px) of a matched measurement
        (NaN on the reference image).
    sigma : numpy.ndarray, shape (k, 2)
        LSM standard deviations (px; NaN on the reference image).
    pairs : dict
        ``(reference id, target id) -> {"candidates", "predicted", "matched",
        "accepted", "flags"}``: candidates of the reference image, those predicted
        inside the target, those the forward match accepted, those kept after
        back-matching, and how many carried each flag.
    """

    point_id: np.ndarray
    image_id: np.ndarray
    image: np.ndarray
    px: np.ndarray
    xy: np.ndarray
    ncc: np.ndarray
    rho: np.ndarray
    back_error: np.ndarray
    sigma: np.ndarray
    pairs: dict = field(default_factory=dict)

    @property
    def n_points(self) -> int:
        """Number of object points."""
        return int(np.unique(self.point_id).size)

    def table(self) -> dict:
        """The measurements: ``point_id, image_id, x, y`` (mm), one row per image."""
        return {"point_id": self.point_id, "image_id": self.image_id,
                "x": self.xy[:, 0], "y": self.xy[:, 1]}

    def indices(self) -> tuple[np.ndarray, np.ndarray]:
        """``(point index, point ids)``: an integer per measurement (0 .. n_points - 1)
        and the ids in that order, for :class:`~vectoradjust.adjust.bundle.BundleProblem`."""
        ids, inv = np.unique(self.point_id, return_inverse=True)
        return inv.astype(np.int64), ids


def tie_settings(**changes) -> MatchSettings:
    """The matching thresholds :func:`tie_points` uses by default.

    :class:`~vectoradjust.measure.transfer.MatchSettings` with a 21 x 21 px template
    (``half_template`` 10), search radius at most 12 px (a larger window is flagged
    ``window_clipped``: the approximate orientation or the heights are too poor), NCC
    and LSM correlation >= 0.8, LSM sigma <= 0.07 px and anisotropy <= 3 (a patch
    textured in one direction only slides along it); ``changes`` override fields.
    """
    base = MatchSettings(half_template=10, max_radius=12.0, max_anisotropy=3.0)
    return dataclasses.replace(base, **changes)


# ---------------------------------------------------------------------- candidates
def foerstner(img: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Foerstner weight ``w`` and roundness ``q`` of every pixel (NaN-free input); also
    :func:`vectoradjust.files.rpc_ties.interest_points`'s operator."""
    gy, gx = np.gradient(img)
    nxx = uniform_filter(gx * gx, window, mode="nearest")
    nyy = uniform_filter(gy * gy, window, mode="nearest")
    nxy = uniform_filter(gx * gy, window, mode="nearest")
    det = nxx * nyy - nxy * nxy
    tr = nxx + nyy
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(tr > 0, det / tr, 0.0)
        q = np.where(tr > 0, 4.0 * det / (tr * tr), 0.0)
    return w, q


def texture_points(image, spacing: int = 32, border: int = 16, window: int = 7,
                   min_roundness: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """The best textured pixel in each cell of a grid over an image.

    Parameters
    ----------
    image : reader or numpy.ndarray
        ``size`` and ``read`` (see the module docstring) or a 2-D array; read whole.
    spacing : int
        Cell size (px).
    border : int
        Pixels kept free at the image edges (at least the template's half size).
    window : int
        Side (px) of the window over which the gradient products are summed.
    min_roundness : float
        Smallest roundness ``q`` in [0, 1] (1: isotropic texture, 0: a straight edge).

    Returns
    -------
    px : numpy.ndarray, shape (m, 2)
        Column, row (array indices) of the chosen pixels.
    weight : numpy.ndarray, shape (m,)
        Their Foerstner weight; cells without a pixel of positive weight and sufficient
        roundness (flat, edges only, NaN) give none.
    """
    rd = _reader(image)
    width, height = (int(v) for v in rd.size)
    img = rd.read(0, 0, width, height)
    bad = ~np.isfinite(img)
    img = np.where(bad, np.nanmean(img) if (~bad).any() else 0.0, img)
    w, q = foerstner(img, window)
    w = np.where((q >= min_roundness) & ~uniform_filter(bad.astype(float), window).astype(bool),
                 w, -np.inf)
    ncol = max((width - 2 * border) // spacing, 0)
    nrow = max((height - 2 * border) // spacing, 0)
    if ncol == 0 or nrow == 0:
        return np.zeros((0, 2)), np.zeros(0)
    sub = w[border:border + nrow * spacing, border:border + ncol * spacing]
    cells = sub.reshape(nrow, spacing, ncol, spacing).transpose(0, 2, 1, 3)
    cells = cells.reshape(nrow * ncol, spacing * spacing)
    k = np.argmax(cells, axis=1)
    best = cells[np.arange(len(k)), k]
    rr, cc = np.divmod(k, spacing)
    ci, ri = np.meshgrid(np.arange(ncol), np.arange(nrow))
    px = np.column_stack([border + ci.ravel() * spacing + cc, border + ri.ravel() * spacing + rr])
    ok = np.isfinite(best) & (best > 0)
    return px[ok].astype(float), best[ok]


# ---------------------------------------------------------------------- matching
def _chips(reader, centres: np.ndarray, half: int) -> tuple[np.ndarray, np.ndarray]:
    """Chips ``(n, 2 half + 1, 2 half + 1)`` around the pixels nearest ``centres`` and the
    pixel (column, row) of each chip's element ``[0, 0]``."""
    c0 = np.round(np.asarray(centres, float)).astype(np.int64) - half
    size = 2 * half + 1
    chips = np.full((len(c0), size, size), np.nan)
    for j, (c, r) in enumerate(c0):
        chips[j] = reader.read(int(c), int(r), size, size)
    return chips, c0.astype(float)


def _inside(px: np.ndarray, size, margin: float) -> np.ndarray:
    """Finite positions at least ``margin`` px inside an image of ``size`` (w, h)."""
    with np.errstate(invalid="ignore"):
        return (np.isfinite(px).all(axis=1) & (px[:, 0] >= margin) & (px[:, 1] >= margin)
                & (px[:, 0] <= size[0] - 1 - margin) & (px[:, 1] <= size[1] - 1 - margin))


def _match(src: ImageGeometry, dst: ImageGeometry, rd_src, rd_dst, px: np.ndarray,
           height: HeightLike, sigma_height: float, sigma_ref_px: float,
           st: MatchSettings) -> dict:
    """Match pixels ``px`` of ``src`` on ``dst``: ``px`` (matched), ``pred``, ``ncc``,
    ``rho``, ``sigma`` and ``flags`` (``off_image`` where the prediction leaves ``dst``)."""
    n = len(px)
    out = {"px": np.full((n, 2), np.nan), "pred": np.full((n, 2), np.nan),
           "ncc": np.full(n, -1.0), "rho": np.full(n, np.nan),
           "sigma": np.full((n, 2), np.nan), "flags": np.zeros(n, np.int64)}
    if n == 0:
        return out
    pred, a = local_affine(src, dst, px, height)
    out["pred"] = pred
    ok = _inside(pred, rd_dst.size, st.half_template + 2) & np.isfinite(a).all(axis=(1, 2))
    out["flags"][~ok] |= TIE_FLAGS["off_image"]
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return out
    ground = src.to_ground(px[idx], height)
    cov = transfer_covariance(src, dst, px[idx], ground, a[idx], sigma_height, sigma_ref_px)
    for s in range(0, idx.size, _BATCH):  # batches: the chips' temporaries stay small
        b, cb = idx[s:s + _BATCH], cov[s:s + _BATCH]
        scale = float(np.abs(a[b]).sum(axis=2).max())
        half_t = int(np.ceil(scale * (st.half_template + st.max_radius) * 1.5)) + 4
        rc, ro = _chips(rd_src, px[b], st.half_template + 3)
        tc, to = _chips(rd_dst, pred[b], half_t)
        res = match_batch(rc, ro, px[b], tc, to, pred[b], a[b], cb, st)
        out["px"][b], out["ncc"][b], out["rho"][b] = res.px, res.ncc, res.rho
        out["sigma"][b] = res.sigma
        out["flags"][b] |= res.flags
    return out


def _pair(geoms, readers, i: int, j: int, px: np.ndarray, height: HeightLike,
          sigma_height: float, sigma_ref_px: float, back_tolerance: float,
          st: MatchSettings) -> tuple[dict, dict]:
    """Forward and back matching of the candidates ``px`` of image ``i`` on image ``j``:
    the forward result with ``back_error`` and the final ``flags``, and the pair's counts."""
    fwd = _match(geoms[i], geoms[j], readers[i], readers[j], px, height, sigma_height,
                 sigma_ref_px, st)
    err = np.full(len(px), np.nan)
    ok = np.flatnonzero(fwd["flags"] == 0)
    back = _match(geoms[j], geoms[i], readers[j], readers[i], fwd["px"][ok], height,
                  sigma_height, sigma_ref_px, st)
    good = back["flags"] == 0
    err[ok[good]] = np.hypot(*(back["px"][good] - px[ok[good]]).T)
    flags = fwd["flags"].copy()
    with np.errstate(invalid="ignore"):
        flags[(flags == 0) & ~(err <= back_tolerance)] |= TIE_FLAGS["back_mismatch"]
    fwd["flags"], fwd["back_error"] = flags, err
    predicted = (flags & TIE_FLAGS["off_image"]) == 0
    counts = {"candidates": int(len(px)), "predicted": int(predicted.sum()),
              "matched": int(len(ok)), "accepted": int(np.sum(flags == 0)),
              "flags": {k: int(np.sum(predicted & ((flags & b) != 0)))
                        for k, b in TIE_FLAGS.items() if k != "off_image"}}
    return fwd, counts


def _check_inputs(geoms: Sequence, images: Sequence) -> None:
    """Geometries and images: as many, at least two, frame geometries."""
    if len(geoms) != len(images):
        raise MeasurementError(
            f"{len(geoms)} image geometries but {len(images)} images",
            "Give one ImageGeometry per image, in the same order")
    if len(geoms) < 2:
        raise MeasurementError(f"tie points need at least two images, not {len(geoms)}",
                               "Give the overlapping images of the block")
    for g in geoms:
        if not isinstance(g, ImageGeometry):
            raise MeasurementError(
                f"tie points need frame images (ImageGeometry), not {type(g).__name__}",
                "For images with RPCs use vectoradjust.files.rpc_ties.rpc_tie_points")
    ids = [g.image_id for g in geoms]
    if len(set(ids)) != len(ids):
        raise MeasurementError(f"image ids repeat: {ids}", "Give each image its own id")


def tie_points(geoms: Sequence[ImageGeometry], images: Sequence, height: HeightLike, *,
               spacing: int = 32, settings: MatchSettings | None = None,
               sigma_height: float = 10.0, sigma_ref_px: float = 0.05,
               back_tolerance: float = 0.5, min_roundness: float = 0.5) -> TiePoints:
    """Measure tie points between frame images (see the module docstring).

    Parameters
    ----------
    geoms : sequence of ImageGeometry
        Approximate orientation of each image; its ``sigma_eo`` (m, rad) widens the
        search windows.
    images : sequence of readers or 2-D arrays
        The grey values, in the order of ``geoms``.
    height : callable or float
        Terrain height ``height(xy (n, 2)) -> z (n,)`` (e.g. a DEM, NaN outside) or a
        constant (m).
    spacing : int
        Grid cell (px) of the candidates on each image.
    settings : MatchSettings, optional
        Matching thresholds (default :func:`tie_settings`).
    sigma_height : float
        Standard deviation (m) of the terrain heights (search window along the epipolar
        line).
    sigma_ref_px : float
        Pointing precision (px) of the candidate on its reference image.
    back_tolerance : float
        Largest distance (px) between the back-matched pixel and the candidate.
    min_roundness : float
        Texture check of the candidates (:func:`texture_points`).

    Returns
    -------
    TiePoints

    Raises
    ------
    MeasurementError
        Geometries and images differ in number, fewer than two images, a geometry that
        is not a frame camera's, repeated image ids.
    """
    _check_inputs(geoms, images)
    readers = [_reader(im) for im in images]
    st = settings or tie_settings()
    rows: dict = {k: [] for k in ("pid", "img", "px", "ncc", "rho", "err", "sig")}
    pairs = {}
    for i, g in enumerate(geoms):
        px, _ = texture_points(readers[i], spacing, st.half_template + 4,
                               min_roundness=min_roundness)
        seen = np.zeros(len(px), bool)
        for j in range(len(geoms)):
            if j == i:
                continue
            fwd, counts = _pair(geoms, readers, i, j, px, height, sigma_height,
                                sigma_ref_px, back_tolerance, st)
            pairs[(g.image_id, geoms[j].image_id)] = counts
            acc = np.flatnonzero(fwd["flags"] == 0)
            seen[acc] = True
            _append(rows, [f"{g.image_id}-{k}" for k in acc], j, fwd["px"][acc],
                    fwd["ncc"][acc], fwd["rho"][acc], fwd["back_error"][acc],
                    fwd["sigma"][acc])
        ref = np.flatnonzero(seen)
        nan = np.full(len(ref), np.nan)
        _append(rows, [f"{g.image_id}-{k}" for k in ref], i, px[ref], nan, nan, nan,
                np.full((len(ref), 2), np.nan))
    return _result(geoms, rows, pairs)


def _append(rows: dict, pid: list, image: int, px, ncc, rho, err, sig) -> None:
    """Add measurements of one image to the row lists."""
    rows["pid"] += pid
    rows["img"].append(np.full(len(pid), image, np.int64))
    for key, val in (("px", px), ("ncc", ncc), ("rho", rho), ("err", err), ("sig", sig)):
        rows[key].append(np.asarray(val, float))


def _result(geoms, rows: dict, pairs: dict) -> TiePoints:
    """The measurements sorted by point and image, with photo coordinates."""
    pid = np.asarray(rows["pid"], dtype=str)
    img = np.concatenate(rows["img"]) if rows["img"] else np.zeros(0, np.int64)
    cat = {k: (np.concatenate(rows[k]) if rows[k] else np.zeros((0, 2) if k in ("px", "sig")
                                                                else (0,)))
           for k in ("px", "ncc", "rho", "err", "sig")}
    order = np.lexsort((img, pid)) if len(pid) else np.zeros(0, np.int64)
    pid, img = pid[order], img[order]
    cat = {k: v[order] for k, v in cat.items()}
    xy = np.zeros((len(pid), 2))
    for i, g in enumerate(geoms):
        m = img == i
        if m.any():
            xy[m] = g.pixel_to_photo(cat["px"][m])
    ids = np.array([g.image_id for g in geoms], dtype=str)
    return TiePoints(pid, ids[img] if len(img) else np.zeros(0, str), img, cat["px"], xy,
                     cat["ncc"], cat["rho"], cat["err"], cat["sig"], pairs)

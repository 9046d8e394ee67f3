"""Automatic tie points between two satellite images with RPCs (rasterio inside functions).

:func:`rpc_tie_points` measures tie points of an image pair the way a stereo pipeline
does before it corrects the relative pointing error (the RPC bias):

1. *Interest points* in image 1 (:func:`interest_points`): one per cell of a regular
   grid, the pixel with the largest Foerstner weight ``w = det(N) / trace(N)`` of the
   structure tensor ``N`` (gradient products summed over a small window) among those
   whose roundness ``q = 4 det(N) / trace(N)^2`` passes a threshold (corners and blobs,
   not edges).
2. *Prediction* in image 2 through the two RPCs at a height: the ray of image 1
   intersected with a DEM/DSM (:func:`dem_height`, or any ``height(lon, lat)``), or a
   constant height (default the RPC's ``HEIGHT_OFF``). The search window is the
   ellipse of the covariance ``sigma_h^2 e e' + sigma_b^2 I`` (``e``: pixels of image 2
   per metre of height along the ray of image 1, i.e. the epipolar direction;
   ``sigma_b``: the relative bias), ``k = 3.717`` (99.9 %) wide. When that window is
   larger than ``settings.max_radius`` (no DEM), a few strong *seed* points are matched
   first with the full window and the others get the heights of their nearest seeds.
3. *Matching* with :func:`vectoradjust.measure.transfer.match_batch` (NCC in the
   template's geometry, then least-squares matching, and its failure flags: correlation,
   LSM precision and anisotropy, ambiguity, window), batched over points.
4. *Back-matching* 2 -> 1 the same way from the matched position; a tie is kept when the
   back-matched position lies within ``back_tolerance`` px of the interest point.

Pixel convention: GDAL's (and :class:`~vectoradjust.sensor.rpc.RpcModel`'s default
``origin="corner"``): ``(0, 0)`` is the upper-left *corner* of the first pixel, so the
array element ``[r, c]`` of a window read at ``(col0, row0)`` (rasterio ``Window``) holds
the value at ``(col0 + c + 0.5, row0 + r + 0.5)``; interest points are pixel centres.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Union

import numpy as np

from vectoradjust.errors import CRSError, DEMError, ProjectError
from vectoradjust.measure.geometry import inv2, window_axes
from vectoradjust.measure.matching import FLAGS
from vectoradjust.measure.ties import foerstner
from vectoradjust.measure.transfer import MatchSettings, match_batch
from vectoradjust.sensor.rpc import RpcModel

__all__ = ["TIE_FLAGS", "RpcTies", "rpc_tie_points", "interest_points", "dem_height",
           "tie_settings", "tie_problem"]

#: flags of a tie (bits): those of :data:`vectoradjust.measure.matching.FLAGS` for the
#: forward match, and:
TIE_FLAGS = {
    **FLAGS,
    "back_mismatch": 256,   # back-matching 2 -> 1 failed or missed by more than the tolerance
    "off_image": 512,       # the prediction falls outside image 2 (or has no height)
}
#: half the central-difference step (px) of the local affine between the images
_AFFINE_STEP = 2.0
#: iterations of the ray / DEM intersection and their convergence (m)
_RAY_ITERATIONS = 12
_RAY_TOL = 0.05
#: floats of the search chips per batch (memory bound of a batch of matches)
_BATCH_FLOATS = 3e7
#: points per batch at most (batches of similar windows)
_BATCH_POINTS = 64
#: nearest seeds whose median height a point without a height gets
_NEIGHBOURS = 4

HeightLike = Union[None, float, str, Path, Callable]


def tie_settings(**changes) -> MatchSettings:
    """The matching thresholds :func:`rpc_tie_points` uses by default.

    :class:`~vectoradjust.measure.transfer.MatchSettings` as the project's transfer uses
    them (NCC and LSM correlation >= 0.8, or >= 0.6 for a distinct peak - every other
    peak 0.1 lower -, LSM sigma <= 0.07 px, ambiguity 0.02) with a
    finite anisotropy limit (3: a patch textured in one direction only slides along it)
    and a 15 px half template (31 x 31 px); ``changes`` override fields.
    """
    return dataclasses.replace(MatchSettings(half_template=15, max_anisotropy=3.0), **changes)


@dataclass
class RpcTies:
    """Tie points between two images (every candidate, accepted or not).

    Attributes
    ----------
    px1 : numpy.ndarray, shape (n, 2)
        Column, row in image 1 (GDAL's corner convention; interest points: pixel centres).
    px2 : numpy.ndarray, shape (n, 2)
        Matched column, row in image 2 (NaN where LSM failed).
    ncc, rho : numpy.ndarray, shape (n,)
        NCC coefficient at the approximate position, correlation coefficient after LSM.
    sigma : numpy.ndarray, shape (n, 2)
        LSM standard deviations of ``px2`` (px).
    back_error : numpy.ndarray, shape (n,)
        Distance (px) of the back-matched position in image 1 from ``px1`` (NaN where
        back-matching failed).
    height : numpy.ndarray, shape (n,)
        Ellipsoidal height (m) the prediction used.
    pred2 : numpy.ndarray, shape (n, 2)
        The RPC prediction in image 2 (without bias).
    interest : numpy.ndarray, shape (n,)
        Foerstner weight of the interest point.
    flags : numpy.ndarray of int, shape (n,)
        Bits of :data:`TIE_FLAGS`; 0 = accepted.
    seeds : int
        Seed points matched with the full height window (0 with a DEM).
    """

    px1: np.ndarray
    px2: np.ndarray
    ncc: np.ndarray
    rho: np.ndarray
    sigma: np.ndarray
    back_error: np.ndarray
    height: np.ndarray
    pred2: np.ndarray
    interest: np.ndarray
    flags: np.ndarray
    seeds: int = 0

    @property
    def accepted(self) -> np.ndarray:
        """Ties without any flag, ``(n,)`` bool."""
        return self.flags == 0

    @property
    def col1(self) -> np.ndarray:
        """Columns in image 1."""
        return self.px1[:, 0]

    @property
    def row1(self) -> np.ndarray:
        """Rows in image 1."""
        return self.px1[:, 1]

    @property
    def col2(self) -> np.ndarray:
        """Columns in image 2."""
        return self.px2[:, 0]

    @property
    def row2(self) -> np.ndarray:
        """Rows in image 2."""
        return self.px2[:, 1]

    def subset(self, mask) -> RpcTies:
        """The ties selected by a boolean mask or index array."""
        m = np.asarray(mask)
        arrays = {f.name: getattr(self, f.name)[m] for f in dataclasses.fields(self)
                  if f.name != "seeds"}
        return RpcTies(**arrays, seeds=self.seeds)

    def count_flags(self) -> dict:
        """How many ties carry each flag (a tie may carry several)."""
        return {k: int(np.sum((self.flags & b) != 0)) for k, b in TIE_FLAGS.items()}


# ---------------------------------------------------------------------- interest points
# (the Foerstner operator: vectoradjust.measure.ties.foerstner)
def interest_points(reader, spacing: int = 48, border: int = 20, window: int = 7,
                    min_roundness: float = 0.5, n: Optional[int] = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The best Foerstner interest point in each cell of a grid over an image.

    Parameters
    ----------
    reader : object
        ``size`` (width, height) and ``read(col0, row0, width, height)`` (float array,
        NaN outside), e.g. :class:`vectoradjust.files.images.RasterioImage`. The image is
        read in stripes of one cell row, so large images need little memory.
    spacing : int
        Cell size (px).
    border : int
        Pixels kept free at the image edges (at least the template's half size).
    window : int
        Side (px) of the window over which the gradient products are summed.
    min_roundness : float
        Smallest roundness ``q`` in [0, 1] (1: isotropic texture, 0: a straight edge).
    n : int, optional
        Keep only the ``n`` points with the largest weight.

    Returns
    -------
    px : numpy.ndarray, shape (m, 2)
        Column, row of the pixel centres (corner convention: ``c + 0.5, r + 0.5``).
    weight : numpy.ndarray, shape (m,)
        Their Foerstner weight (grey value^2 per pixel^2); cells without a point whose
        weight is positive and roundness sufficient give none.
    """
    width, height = (int(v) for v in reader.size)
    pad = window // 2 + 2
    x0, x1, y0, y1 = border, width - border, border, height - border
    ncol = max((x1 - x0) // spacing, 0)
    pts, wts = [], []
    if ncol == 0:
        return np.zeros((0, 2)), np.zeros(0)
    for r0 in range(y0, y1 - spacing + 1, spacing):
        lo, hi = max(r0 - pad, 0), min(r0 + spacing + pad, height)
        img = reader.read(0, lo, width, hi - lo)
        img = np.where(np.isfinite(img), img, np.nanmean(img) if np.isfinite(img).any() else 0)
        # beyond the image edge: the edge rows repeated (no artificial edge there)
        img = np.pad(img, ((lo - (r0 - pad), r0 + spacing + pad - hi), (0, 0)), mode="edge")
        w, q = foerstner(img, window)
        w = np.where(q >= min_roundness, w, -np.inf)[pad:pad + spacing, x0:x0 + ncol * spacing]
        cells = w.reshape(spacing, ncol, spacing).transpose(1, 0, 2).reshape(ncol, -1)
        k = np.argmax(cells, axis=1)
        best = cells[np.arange(ncol), k]
        rr, cc = np.divmod(k, spacing)
        ok = np.isfinite(best) & (best > 0)
        pts.append(np.column_stack([x0 + np.arange(ncol) * spacing + cc + 0.5,
                                    r0 + rr + 0.5])[ok])
        wts.append(best[ok])
    px = np.concatenate(pts) if pts else np.zeros((0, 2))
    wt = np.concatenate(wts) if wts else np.zeros(0)
    if n is not None and len(wt) > n:
        keep = np.sort(np.argsort(-wt, kind="stable")[:n])
        px, wt = px[keep], wt[keep]
    return px, wt


# ---------------------------------------------------------------------- heights
def dem_height(path) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """A height function ``h(lon, lat)`` (WGS84 degrees) from a DEM or DSM GeoTIFF.

    Bilinear between cell centres (:func:`vectoradjust.adjust.dem.bilinear`), NaN outside
    the grid and next to nodata cells. The DEM must hold *ellipsoidal* heights (as RPCs
    use them; convert orthometric heights with the geoid first).

    Parameters
    ----------
    path : str or os.PathLike
        A north-up raster with a CRS (:func:`vectoradjust.files.readers.read_dem`).

    Raises
    ------
    DEMError
        The file is missing, unreadable or rotated.
    CRSError
        The DEM has no CRS.
    """
    from pyproj import Transformer

    from vectoradjust.adjust.dem import bilinear
    from vectoradjust.files.readers import read_dem

    if not Path(path).is_file():
        raise DEMError(f"DEM {str(path)!r} does not exist",
                       "Give a DEM or DSM GeoTIFF with ellipsoidal heights as height=, a "
                       "height in metres, or None (the RPC's height offset)", path=str(path))
    grid, gt, nodata, crs = read_dem(str(path))
    if crs is None:
        raise CRSError(f"{path}: the DEM has no coordinate reference system",
                       "Assign its CRS to the GeoTIFF (gdal_edit.py -a_srs)", path=str(path))
    horizontal = crs.sub_crs_list[0] if crs.is_compound else crs
    t = Transformer.from_crs("EPSG:4326", horizontal, always_xy=True)

    def height(lon, lat) -> np.ndarray:
        x, y = t.transform(np.asarray(lon, float), np.asarray(lat, float))
        return bilinear(grid, gt, np.column_stack([np.ravel(x), np.ravel(y)]), nodata=nodata)

    return height


def _height_source(height: HeightLike, rpc: RpcModel):
    """``(function or None, constant)`` from the ``height`` argument."""
    if height is None:
        return None, float(rpc.height_off)
    if callable(height):
        return height, np.nan
    if isinstance(height, (str, Path)):
        return dem_height(height), np.nan
    try:
        value = float(height)
    except (TypeError, ValueError):
        raise ProjectError(f"height {height!r} is neither a number, a DEM file nor a "
                           "function", "Give a DEM/DSM GeoTIFF (ellipsoidal heights), a "
                           "height in metres, a function h(lon, lat), or None") from None
    if not np.isfinite(value):
        raise ProjectError(f"height {height!r} is not finite", "Give a height in metres")
    return None, value


def _ray_heights(rpc: RpcModel, px: np.ndarray, fn: Callable, start: float) -> np.ndarray:
    """Heights where the rays of pixels of ``rpc`` meet the surface ``fn`` (NaN where the
    surface has no value or the fixed-point iteration does not settle)."""
    h = np.full(len(px), float(start))
    done = np.zeros(len(px), bool)
    for _ in range(_RAY_ITERATIONS):
        ll = rpc.localize(px[:, 0], px[:, 1], h)
        new = np.asarray(fn(ll[:, 0], ll[:, 1]), float).reshape(-1)
        with np.errstate(invalid="ignore"):
            done = np.abs(new - h) < _RAY_TOL
        h = new
        if np.all(done | ~np.isfinite(h)):
            break
    return np.where(done, h, np.nan)


def _fill_heights(px: np.ndarray, h: np.ndarray, known: np.ndarray, sigma: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Heights and their sigmas: the known ones with ``sigma``; the others the median of
    their nearest known points'. Their sigma is twice the robust spread (NMAD) of the
    known heights about such medians (leave-one-out), times the distance to the nearest
    known point in units of the known points' own median spacing (at least 1), and at
    least ``sigma``: the further from known heights, the wider the window."""
    from scipy.spatial import cKDTree

    h = np.array(h, float)
    s = np.full(len(h), float(sigma))
    idx = np.flatnonzero(known)
    if idx.size == 0 or idx.size == len(h):
        return h, s
    k = min(_NEIGHBOURS, idx.size)
    tree = cKDTree(px[idx])
    spread, spacing = 0.0, 1.0
    if idx.size > 1:  # leave-one-out prediction error of the known heights
        dist, nb = tree.query(px[idx], k=min(k + 1, idx.size))
        loo = np.median(h[idx][nb[:, 1:]], axis=1)
        spread = 1.4826 * float(np.median(np.abs(h[idx] - loo)))
        spacing = max(float(np.median(dist[:, 1])), 1.0)
    rest = np.flatnonzero(~known)
    dist, nb = tree.query(px[rest], k=k)
    h[rest] = np.median(h[idx][np.reshape(nb, (len(rest), -1))], axis=1)
    far = np.maximum(np.reshape(dist, (len(rest), -1))[:, 0] / spacing, 1.0)
    s[rest] = np.maximum(float(sigma), 2.0 * spread * far)
    return h, s


# ---------------------------------------------------------------------- geometry
def _transfer_geometry(rpc_a: RpcModel, rpc_b: RpcModel, px: np.ndarray, h: np.ndarray):
    """Prediction of pixels of image a in image b at heights ``h``: positions ``(n, 2)``,
    the local affine ``d px_b / d px_a`` at constant height ``(n, 2, 2)`` and the
    epipolar vector ``d px_b / d h`` along the ray of a ``(n, 2)`` (px per m)."""
    d = _AFFINE_STEP
    offs = np.array([[0, 0], [d, 0], [-d, 0], [0, d], [0, -d], [0, 0]], float)
    n = len(px)
    pp = (px[None] + offs[:, None]).reshape(-1, 2)
    hh = np.concatenate([np.tile(h, 5), h + 1.0])
    ll = rpc_a.localize(pp[:, 0], pp[:, 1], hh)
    q = rpc_b.project(ll[:, 0], ll[:, 1], hh).reshape(6, n, 2)
    a = np.empty((n, 2, 2))
    a[:, :, 0] = (q[1] - q[2]) / (2 * d)
    a[:, :, 1] = (q[3] - q[4]) / (2 * d)
    return q[0], a, q[5] - q[0]


def _window_cov(e: np.ndarray, sigma_h: np.ndarray, sigma_b: float) -> np.ndarray:
    """Covariance of a prediction: height along the epipolar vector plus the bias."""
    return (np.asarray(sigma_h, float)[:, None, None] ** 2 * e[:, :, None] * e[:, None, :]
            + float(sigma_b) ** 2 * np.eye(2))


def _radius(a: np.ndarray, cov: np.ndarray, k: float) -> np.ndarray:
    """Semi-major axis (px of the reference image) of each search window."""
    ai = inv2(a)
    return window_axes(ai @ cov @ np.swapaxes(ai, 1, 2), k)[:, 0] + 1.0


def _parallax_heights(rpc1: RpcModel, rpc2: RpcModel, px1: np.ndarray, px2: np.ndarray,
                      h: np.ndarray, iterations: int = 4) -> np.ndarray:
    """Heights of matched points along the ray of image 1 (least squares on the epipolar
    component of image 2, which the across-track bias does not change)."""
    h = np.array(h, float)
    for _ in range(iterations):
        pred, _, e = _transfer_geometry(rpc1, rpc2, px1, h)
        h = h + np.sum(e * (px2 - pred), axis=1) / np.sum(e * e, axis=1)
    return h


# ---------------------------------------------------------------------- matching
def _read_chips(reader, centres: np.ndarray, half: int) -> tuple[np.ndarray, np.ndarray]:
    """Chips ``(n, 2 half + 1, 2 half + 1)`` centred on the pixels that contain
    ``centres`` (corner convention), and the image position of each chip's element
    ``[0, 0]``: its pixel centre, ``col0 + 0.5, row0 + 0.5``."""
    c0 = np.floor(np.asarray(centres, float)).astype(np.int64) - half
    size = 2 * half + 1
    chips = np.full((len(c0), size, size), np.nan)
    for j, (c, r) in enumerate(c0):  # I/O: one window per point
        chips[j] = reader.read(int(c), int(r), size, size)
    return chips, c0 + 0.5


def _inside(px: np.ndarray, size, margin: float) -> np.ndarray:
    """Finite positions at least ``margin`` px inside an image of ``size`` (w, h)."""
    with np.errstate(invalid="ignore"):
        return (np.isfinite(px).all(axis=1) & (px[:, 0] >= margin) & (px[:, 1] >= margin)
                & (px[:, 0] <= size[0] - margin) & (px[:, 1] <= size[1] - margin))


def _match(readers, rpcs, px: np.ndarray, h: np.ndarray, sigma_h: np.ndarray,
           sigma_b: float, st: MatchSettings, cap: float) -> dict:
    """Match pixels of image ``readers[0]`` on image ``readers[1]`` at heights ``h``.

    The search window covers the height sigmas along the epipolar direction and the bias
    sigma in every direction (radius capped at ``cap`` px); batches keep the search chips
    within :data:`_BATCH_FLOATS`. Returns ``px, ncc, rho, sigma, flags, pred``.
    """
    n = len(px)
    out = {"px": np.full((n, 2), np.nan), "ncc": np.full(n, -1.0), "rho": np.full(n, np.nan),
           "sigma": np.full((n, 2), np.nan), "flags": np.zeros(n, np.int64),
           "pred": np.full((n, 2), np.nan)}
    if n == 0:
        return out
    pred, a, e = _transfer_geometry(rpcs[0], rpcs[1], px, h)
    out["pred"] = pred
    cov = _window_cov(e, sigma_h, sigma_b)
    reach = st.k * np.asarray(sigma_h, float)[:, None] * e  # the window's ends
    ok = np.zeros(n, bool)
    for t in (0.0, -1.0, 1.0, -0.5, 0.5):  # the epipolar segment enters image 2
        ok |= _inside(pred + t * reach, readers[1].size, st.half_template)
    ok &= np.isfinite(cov).all(axis=(1, 2))
    out["flags"][~ok] |= TIE_FLAGS["off_image"]
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return out
    rad = np.clip(_radius(a[idx], cov[idx], st.k), 3.0, cap)
    order = np.argsort(rad, kind="stable")
    idx, rad = idx[order], rad[order]
    floats = 6.0 * (2 * (st.half_template + np.ceil(rad)) + 1) ** 2  # per point
    s = 0
    while s < idx.size:  # batches of similar windows, the largest radius of each
        fit = np.arange(1, idx.size - s + 1) * floats[s:] <= _BATCH_FLOATS
        e = s + max(1, min(int(fit.sum()), _BATCH_POINTS))
        b, s = idx[s:e], e
        stb = dataclasses.replace(st, max_radius=float(rad[e - 1]))
        hw = st.half_template + int(np.ceil(stb.max_radius))
        grow = float(np.abs(a[b]).sum(axis=2).max())
        rc, ro = _read_chips(readers[0], px[b], st.half_template + 3)
        tc, to = _read_chips(readers[1], pred[b], int(np.ceil(grow * hw)) + 4)
        res = match_batch(rc, ro, px[b], tc, to, pred[b], a[b], cov[b], stb)
        out["px"][b], out["ncc"][b], out["rho"][b] = res.px, res.ncc, res.rho
        out["sigma"][b] = res.sigma
        out["flags"][b] |= res.flags
    return out


def _seed_heights(readers, rpcs, px1: np.ndarray, weight: np.ndarray, h0: np.ndarray,
                  sigma0: np.ndarray, sigma_b: float, st: MatchSettings, cap: float,
                  n_seeds: int) -> tuple[np.ndarray, np.ndarray]:
    """Seed points matched with the full height window: their indices and heights.

    The seeds are the strongest interest points of the cells of a ``g x g`` grid over the
    points (``g^2 ~ n_seeds``), so that they spread over the image.
    """
    g = max(1, int(round(np.sqrt(n_seeds))))
    lo, hi = px1.min(axis=0), px1.max(axis=0) + 1e-9
    cell = np.floor((px1 - lo) / (hi - lo) * g).astype(np.int64)
    key = cell[:, 1] * g + cell[:, 0]
    order = np.lexsort((-weight, key))
    pick = order[np.r_[True, key[order][1:] != key[order][:-1]]]
    res = _match(readers, rpcs, px1[pick], h0[pick], sigma0[pick], sigma_b, st, cap)
    acc = res["flags"] == 0
    hh = _parallax_heights(rpcs[0], rpcs[1], px1[pick[acc]], res["px"][acc], h0[pick[acc]])
    good = np.isfinite(hh)
    return pick[acc][good], hh[good]


def _prediction_heights(readers, rpcs, px1: np.ndarray, weight: np.ndarray,
                        height: HeightLike, height_sigma: Optional[float], sigma_b: float,
                        st: MatchSettings, cap: float, n_seeds: int):
    """Heights, their sigmas and the number of seeds for the prediction of every point."""
    fn, const = _height_source(height, rpcs[0])
    n = len(px1)
    domain = rpcs[0].height_scale / st.k  # the window then spans the RPC's heights
    if fn is not None:
        ll = rpcs[0].localize(px1[:, 0], px1[:, 1], np.full(n, rpcs[0].height_off))
        first = np.asarray(fn(ll[:, 0], ll[:, 1]), float).reshape(-1)
        start = np.nanmedian(first) if np.isfinite(first).any() else rpcs[0].height_off
        h = _ray_heights(rpcs[0], px1, fn, start)
        sigma = _DEM_SIGMA if height_sigma is None else float(height_sigma)
        known = np.isfinite(h)
        h = np.where(known, h, start)
    else:
        sigma = domain if height_sigma is None else float(height_sigma)
        h, known = np.full(n, const), np.ones(n, bool)
    _, a, e = _transfer_geometry(rpcs[0], rpcs[1], px1, h)
    rad = _radius(a, _window_cov(e, np.full(n, sigma), sigma_b), st.k)
    small = known & (rad <= st.max_radius)
    if small.sum() >= min(3, n):
        h, s = _fill_heights(px1, h, small, sigma)
        return h, s, 0
    seeds, hs = _seed_heights(readers, rpcs, px1, weight, h,
                              np.where(known, sigma, max(sigma, domain)), sigma_b, st, cap,
                              n_seeds)
    if seeds.size == 0:
        raise ProjectError(
            f"no seed point of {min(n_seeds, n)} could be matched with a search window of "
            f"{cap:.0f} px along the epipolar line (height {np.median(h):.1f} m +- "
            f"{st.k * sigma:.0f} m)",
            "Give a DEM or DSM with ellipsoidal heights (height=...), or a height closer "
            "to the terrain's with a smaller height_sigma, or a larger max_search")
    h[seeds] = hs
    known = np.zeros(n, bool)
    known[seeds] = True
    h, s = _fill_heights(px1, h, known, min(sigma, _DEM_SIGMA))
    return h, s, int(seeds.size)


#: height sigma (m) of a DEM by default, and the least of heights taken from neighbours
_DEM_SIGMA = 5.0


def _inputs(image_paths: Sequence, rpcs: Optional[Sequence]) -> tuple[list, list]:
    """The two image paths and their RPC models (read from the images when not given)."""
    from vectoradjust.files.rpc import read_rpc

    paths = [Path(p) for p in image_paths]
    if len(paths) != 2:
        raise ProjectError(f"tie points need two images, not {len(paths)}",
                           "Give the reference image and the other image")
    models = list(rpcs) if rpcs is not None else [None, None]
    if len(models) != 2:
        raise ProjectError(f"{len(models)} RPC models for two images",
                           "Give one RpcModel per image (or None to read it from the image)")
    models = [read_rpc(p) if m is None else m for p, m in zip(paths, models)]
    for p, m in zip(paths, models):
        if not isinstance(m, RpcModel):
            raise ProjectError(f"the RPCs of {p} are a {type(m).__name__}, not an RpcModel",
                               "Read them with vectoradjust.files.rpc.read_rpc")
    return paths, models


def _back_match(readers, rpcs, fwd: dict, px1: np.ndarray, h: np.ndarray, s: np.ndarray,
                sigma_b: float, st: MatchSettings, cap: float) -> np.ndarray:
    """Distance (px) of the back-matched (2 -> 1) position from ``px1`` (NaN: failed)."""
    err = np.full(len(px1), np.nan)
    ok = np.flatnonzero(fwd["flags"] == 0)
    back = _match(readers[::-1], rpcs[::-1], fwd["px"][ok], h[ok], s[ok], sigma_b, st, cap)
    good = back["flags"] == 0
    err[ok[good]] = np.hypot(*(back["px"][good] - px1[ok[good]]).T)
    return err


def rpc_tie_points(image_paths: Sequence, rpcs: Optional[Sequence] = None,
                   height: HeightLike = None, *, height_sigma: Optional[float] = None,
                   bias_sigma: float = 3.0, spacing: int = 48, n: Optional[int] = None,
                   settings: Optional[MatchSettings] = None, back_tolerance: float = 0.5,
                   min_roundness: float = 0.5, max_search: float = 800.0,
                   n_seeds: int = 16) -> RpcTies:
    """Measure tie points between two images with RPCs (see the module docstring).

    Parameters
    ----------
    image_paths : sequence of 2 paths
        Image 1 (where the interest points are chosen) and image 2; grey value: the mean
        of the bands (:class:`vectoradjust.files.images.RasterioImage`).
    rpcs : sequence of 2 RpcModel or None, optional
        Their RPCs (default: read from the images, :func:`vectoradjust.files.rpc.read_rpc`).
    height : None, float, path or callable
        The surface the rays of image 1 are intersected with: a DEM/DSM GeoTIFF
        (*ellipsoidal* heights, :func:`dem_height`), a function ``h(lon, lat)`` (NaN where
        unknown), a constant ellipsoidal height (m), or None: the ``HEIGHT_OFF`` of
        image 1's RPC. Points without a DEM height get the median height of their nearest
        neighbours (with the spread of those heights in the window).
    height_sigma : float, optional
        Standard deviation (m) of those heights: the search window's extent along the
        epipolar direction. Default: 5 m for a DEM or function; ``HEIGHT_SCALE / 3.717``
        for a constant, so that the window covers the RPC's height domain (then seed
        points are matched first, see the module docstring).
    bias_sigma : float
        Standard deviation (px) of the relative bias between the RPCs (window in every
        direction).
    spacing : int
        Grid cell (px) of the interest points in image 1: one candidate per cell.
    n : int, optional
        At most this many candidates (the strongest).
    settings : MatchSettings, optional
        Matching thresholds (default :func:`tie_settings`); ``max_radius`` is the largest
        window matched without seed points; the radius used is the window's own.
    back_tolerance : float
        Largest distance (px) between the back-matched and the original point of image 1.
    min_roundness : float
        Roundness threshold of the interest operator (:func:`interest_points`).
    max_search : float
        Largest search radius (px) of seed points.
    n_seeds : int
        Number of seed points when the height window is too large.

    Returns
    -------
    RpcTies
        Every candidate with its flags; ``ties.subset(ties.accepted)`` keeps the accepted.

    Raises
    ------
    InputFileError
        An image is missing or unreadable, or has no RPCs.
    DEMError, CRSError
        The DEM is unreadable or has no CRS.
    ProjectError
        Not two images; no seed point could be matched.
    """
    from vectoradjust.files.images import RasterioImage

    paths, models = _inputs(image_paths, rpcs)
    readers = [RasterioImage(p, f"image {i + 1}") for i, p in enumerate(paths)]
    try:
        st = settings or tie_settings()
        px1, wt = interest_points(readers[0], spacing, border=st.half_template + 4,
                                  min_roundness=min_roundness, n=n)
        h, s, seeds = _prediction_heights(readers, models, px1, wt, height, height_sigma,
                                          bias_sigma, st, max_search, n_seeds)
        fwd = _match(readers, models, px1, h, s, bias_sigma, st, max_search)
        err = _back_match(readers, models, fwd, px1, h, s, bias_sigma, st, max_search)
    finally:
        for r in readers:
            r.close()
    flags = fwd["flags"].copy()
    with np.errstate(invalid="ignore"):
        flags[(flags == 0) & ~(err <= back_tolerance)] |= TIE_FLAGS["back_mismatch"]
    return RpcTies(px1, fwd["px"], fwd["ncc"], fwd["rho"], fwd["sigma"], err, h, fwd["pred"],
                   wt, flags, seeds)


def tie_problem(ties: RpcTies, rpcs: Sequence, frame, bias: Sequence = ("none", "shift"),
                height: HeightLike = None, height_sigma: float = 5.0,
                obs_sigma: float = 0.1):
    """A bundle adjustment of the two images from the accepted tie points.

    Parameters
    ----------
    ties : RpcTies
        From :func:`rpc_tie_points`; only the accepted ties are used, point ``k`` of the
        problem is the ``k``-th of them.
    rpcs : sequence of 2 RpcModel
    frame : GroundFrame
        Object coordinates to geodetic, e.g.
        :func:`vectoradjust.files.rpc.crs_frame` (``"EPSG:327zz"``, ellipsoidal heights).
    bias : sequence of 2 str
        Bias model of each image (:data:`vectoradjust.sensor.rpc.BIAS_MODELS`); the
        default estimates the shift of image 2 relative to image 1 (held fixed).
    height : None, float, path or callable
        Optional height prior of every point: a DEM/DSM (ellipsoidal heights), a
        function ``h(lon, lat)`` or a constant (m), sampled at the point's approximate
        position. Without it the points have no prior: two images and a shift leave the
        shift along the epipolar direction nearly undetermined (it moves every height
        alike), which a height prior fixes.
    height_sigma : float
        Standard deviation (m) of the height prior (weight along the ellipsoid normal).
    obs_sigma : float
        Standard deviation (px) of each image coordinate.

    Returns
    -------
    vectoradjust.adjust.bundle.BundleProblem
        ``sensors`` holds the two :class:`~vectoradjust.sensor.models.RpcImage`; the
        approximate points come from the RPCs without bias
        (:func:`vectoradjust.adjust.intersection.rpc_intersection`).
    """
    from vectoradjust.adjust.bundle import BundleProblem
    from vectoradjust.adjust.intersection import rpc_intersection
    from vectoradjust.sensor.models import RpcImage, SensorSet

    acc = ties.subset(ties.accepted)
    m = len(acc.flags)
    sensors = SensorSet([RpcImage(r, b) for r, b in zip(rpcs, bias)], frame)
    op, oi = np.repeat(np.arange(m), 2), np.tile([0, 1], m)
    obs = np.stack([acc.px1, acc.px2], axis=1).reshape(-1, 2)
    xyz0 = rpc_intersection(sensors, np.zeros((2, 6)), op, oi, obs, m)
    prior, weight = np.zeros((m, 3)), np.zeros((m, 3, 3))
    fn = None
    if height is not None:
        fn, const = _height_source(height, rpcs[0])
        if fn is None:
            def fn(lon, lat):  # a constant height
                return np.full(np.shape(lon), const)
    if fn is not None and m:
        llh, jac = frame.to_geodetic(xyz0)
        z = np.asarray(fn(llh[:, 0], llh[:, 1]), float).reshape(-1)
        ok = np.isfinite(z)
        prior[ok] = frame.from_geodetic(np.column_stack([llh[ok, :2], z[ok]]))
        g = jac[ok, 2, :]  # d h / d(X, Y, Z): the height's direction in the frame
        weight[ok] = g[:, :, None] * g[:, None, :] / float(height_sigma) ** 2
    return BundleProblem(np.nan, (0.0, 0.0), np.zeros((2, 6)), np.full((2, 6), np.inf), xyz0,
                         prior, weight, op, oi, obs, np.full(obs.shape, float(obs_sigma)),
                         sensors=sensors)

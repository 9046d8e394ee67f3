"""Area-based matching: normalised cross-correlation and least-squares matching.

Everything is batched over points: ``n`` templates of the same size are matched in ``n``
search chips of the same size at once (no Python loop over points).

* :func:`ncc_search` - the normalised cross-correlation coefficient of a template at
  every position of a search chip, by FFT (the local sums of the chip by summed-area
  tables), the best position inside an allowed region with a sub-pixel parabola fit.
* :func:`ncc_pyramid` - the same coarse-to-fine: the peak found at 1/4 and 1/2 of the
  resolution in the whole window, then refined at full resolution near it.
* :func:`lsm` - least-squares matching (Gruen 1985, "Adaptive least squares correlation"):
  ``g1(u, v) + e = r0 + r1 g2(t + A (u, v))`` with an affine geometric transformation
  ``(A, t)`` and a linear radiometric one ``(r0, r1)``, solved by Gauss-Newton; the
  precision of the shift from ``sigma0^2 N^-1`` and the correlation coefficient of the
  matched patches; :func:`residual_inflation` - how much correlated residuals widen
  that precision.

Coordinates are pixel (column, row) of the chip arrays ``chip[row, column]``; a chip's
pixel ``(c, r)`` holds the value at its centre.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import fft as sfft
from scipy.ndimage import maximum_filter, uniform_filter

__all__ = [
    "NCCResult",
    "LSMResult",
    "ncc_surface",
    "ncc_search",
    "ncc_pyramid",
    "sample",
    "lsm",
    "FLAGS",
    "texture_measures",
    "residual_inflation",
]

#: Failure flags of a match (bits of ``flags``): a match with any flag is not accepted.
FLAGS = {
    "low_correlation": 1,      # correlation coefficient below the threshold
    "not_converged": 2,        # LSM did not converge in its iterations
    "outside_window": 4,       # the match lies outside the search window
    "poor_precision": 8,       # LSM sigma of the shift above the limit
    "edge": 16,                # template or search window leaves the image
    "no_texture": 32,          # template without contrast (NCC undefined)
    "ambiguous": 64,           # second NCC peak nearly as high as the first
    "window_clipped": 128,     # the search window was larger than the largest radius
    "back_mismatch": 256,      # matching back to the reference missed it (or failed)
    "inconsistent": 1024,      # the forward intersection of all its images misses it
}


def flag_names(flags: int) -> str:
    """The names of the bits set in ``flags``, joined by ``|`` (``""`` for none)."""
    return "|".join(k for k, b in FLAGS.items() if int(flags) & b)


@dataclass
class NCCResult:
    """Best NCC position of each template in its chip.

    Attributes
    ----------
    pos : numpy.ndarray, shape (n, 2)
        Sub-pixel (column, row) of the template centre in the search chip.
    ncc : numpy.ndarray, shape (n,)
        Correlation coefficient at the integer peak.
    second : numpy.ndarray, shape (n,)
        Highest other local maximum (3 x 3) more than 3 pixels from the peak.
    """

    pos: np.ndarray
    ncc: np.ndarray
    second: np.ndarray


def ncc_surface(templates: np.ndarray, chips: np.ndarray) -> np.ndarray:
    """Correlation coefficient of each template at every position of its chip.

    Parameters
    ----------
    templates : numpy.ndarray, shape (n, th, tw)
    chips : numpy.ndarray, shape (n, H, W)

    Returns
    -------
    numpy.ndarray, shape (n, H - th + 1, W - tw + 1)
        Entry ``[i, r, c]``: template ``i`` over chip ``i``'s window with top-left
        ``(r, c)``. NaN where the window or the template has no contrast.
    """
    t = np.asarray(templates, float)
    s = np.asarray(chips, float)
    n, th, tw = t.shape
    _, hh, ww = s.shape
    m = th * tw
    tz = t - t.mean(axis=(1, 2), keepdims=True)
    tnorm = np.sqrt(np.sum(tz * tz, axis=(1, 2)))
    shape = (hh + th - 1, ww + tw - 1)
    fshape = [sfft.next_fast_len(v, real=True) for v in shape]
    fs = sfft.rfft2(s, fshape, axes=(1, 2))
    ft = sfft.rfft2(tz[:, ::-1, ::-1], fshape, axes=(1, 2))
    full = sfft.irfft2(fs * ft, fshape, axes=(1, 2))
    num = full[:, th - 1:hh, tw - 1:ww]
    s1 = _box_sums(s, th, tw)
    s2 = _box_sums(s * s, th, tw)
    var = np.clip(s2 - s1 * s1 / m, 0.0, None)
    den = np.sqrt(var) * tnorm[:, None, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        out = num / den
    tiny = 1e-9 * (np.abs(s).max(axis=(1, 2)) + 1.0)[:, None, None] ** 2 * m
    out[den <= tiny] = np.nan
    return out


def _box_sums(a: np.ndarray, th: int, tw: int) -> np.ndarray:
    """Sums of ``a`` over every ``th x tw`` window (summed-area table), batched."""
    c = np.zeros((a.shape[0], a.shape[1] + 1, a.shape[2] + 1))
    c[:, 1:, 1:] = a.cumsum(axis=1).cumsum(axis=2)
    return c[:, th:, tw:] - c[:, :-th, tw:] - c[:, th:, :-tw] + c[:, :-th, :-tw]


def ncc_search(templates: np.ndarray, chips: np.ndarray,
               allowed: np.ndarray | None = None,
               peak_region: np.ndarray | None = None) -> NCCResult:
    """Best NCC position of each template in its chip, sub-pixel.

    Parameters
    ----------
    templates : numpy.ndarray, shape (n, th, tw)
        Odd sizes; the template centre is its middle pixel.
    chips : numpy.ndarray, shape (n, H, W)
    allowed : numpy.ndarray of bool, shape (n, H - th + 1, W - tw + 1), optional
        Positions (top-left) the peak may take (the search window).
    peak_region : numpy.ndarray of bool, same shape as ``allowed``, optional
        Where the peak is taken (e.g. near the peak of a coarser pyramid level); the
        ``second`` peak is still looked for in the whole ``allowed`` window.

    Returns
    -------
    NCCResult
        ``pos`` is the chip (column, row) of the template centre; a parabola through
        the peak and its neighbours gives the sub-pixel part. ``ncc`` is -1 where no
        position is defined.
    """
    t = np.asarray(templates, float)
    n, th, tw = t.shape
    rho = ncc_surface(t, chips)
    r = np.where(np.isfinite(rho), rho, -np.inf)
    if allowed is not None:
        r = np.where(allowed, r, -np.inf)
    h, w = r.shape[1:]
    flat = (r if peak_region is None else np.where(peak_region, r, -np.inf)).reshape(n, -1)
    k = np.argmax(flat, axis=1)
    best = flat[np.arange(n), k]
    rr, cc = np.divmod(k, w)
    sub = np.zeros((n, 2))
    for axis, (i0, lim) in enumerate(((cc, w), (rr, h))):
        lo = np.clip(i0 - 1, 0, lim - 1)
        hi = np.clip(i0 + 1, 0, lim - 1)
        if axis == 0:
            f0, fm, fp = best, r[np.arange(n), rr, lo], r[np.arange(n), rr, hi]
        else:
            f0, fm, fp = best, r[np.arange(n), lo, cc], r[np.arange(n), hi, cc]
        with np.errstate(invalid="ignore"):
            den = fm - 2 * f0 + fp
        ok = np.isfinite(den) & (den < 0) & (lo != i0) & (hi != i0)
        with np.errstate(invalid="ignore", divide="ignore"):
            d = np.where(ok, 0.5 * (fm - fp) / np.where(ok, den, 1.0), 0.0)
        sub[:, axis] = np.clip(d, -0.5, 0.5)
    yy, xx = np.mgrid[0:h, 0:w]
    near = ((yy[None] - rr[:, None, None]) ** 2 + (xx[None] - cc[:, None, None]) ** 2) <= 9
    peaks = (r == maximum_filter(r, size=(1, 3, 3), mode="nearest")) & np.isfinite(r)
    second = np.where(near | ~peaks, -np.inf, r).reshape(n, -1).max(axis=1)
    pos = np.column_stack([cc + sub[:, 0] + (tw - 1) / 2.0, rr + sub[:, 1] + (th - 1) / 2.0])
    best = np.where(np.isfinite(best), best, -1.0)
    second = np.where(np.isfinite(second), second, -1.0)
    return NCCResult(pos, best, second)


def ncc_pyramid(templates: np.ndarray, chips: np.ndarray, allowed: np.ndarray | None = None,
                levels: int = 2, radius: float = 1.5) -> NCCResult:
    """Coarse-to-fine NCC over an image pyramid.

    Template and chip are smoothed by a ``f x f`` box and decimated by ``f = 2^L`` for
    ``L = levels ... 1``; the coarsest level finds the peak in the whole ``allowed``
    window, each finer level only within ``radius`` times the coarser level's factor
    (full-resolution pixels) of the coarser peak, and full resolution refines it
    (:func:`ncc_search` with ``peak_region``, so that ``second`` - the ambiguity - is
    still that of the whole window). At the coarse levels the noise, JPEG blocks and
    small geometric differences are averaged out, so that a broad true peak is found in
    a large window before the fine texture places it.

    Parameters
    ----------
    templates : numpy.ndarray, shape (n, th, tw)
        Odd sizes.
    chips : numpy.ndarray, shape (n, H, W)
    allowed : numpy.ndarray of bool, shape (n, H - th + 1, W - tw + 1), optional
    levels : int
        Number of coarse levels (0: :func:`ncc_search` alone); a level whose decimated
        template would be smaller than 5 x 5 is skipped.
    radius : float
        Search radius around a coarser level's peak, in that level's pixels.

    Returns
    -------
    NCCResult
        As :func:`ncc_search` at full resolution.
    """
    t = np.asarray(templates, float)
    s = np.asarray(chips, float)
    n, th, tw = t.shape
    hh, ww = s.shape[1] - th + 1, s.shape[2] - tw + 1
    ok = np.ones((n, hh, ww), bool) if allowed is None else np.asarray(allowed, bool)
    yy, xx = np.mgrid[0:hh, 0:ww]
    centre = None  # (n, 2) full-resolution top-left (column, row) of the coarser peak
    for lev in range(int(levels), 0, -1):
        f = 2 ** lev
        kr, kc = (th - 1) // 2 // f, (tw - 1) // 2 // f
        if min(kr, kc) < 2:
            continue
        region = ok if centre is None else _near(xx, yy, centre, radius * 2 * f)
        centre = _coarse_peak(t, s, ok & region, f, kr, kc)
    region = None if centre is None else _near(xx, yy, centre, radius * 2)
    return ncc_search(t, s, ok, region)


def _near(xx: np.ndarray, yy: np.ndarray, centre: np.ndarray, r: float) -> np.ndarray:
    """Positions within ``r`` of each ``centre`` (column, row), shape (n, H, W); all
    positions where the centre is NaN (no coarse peak)."""
    d2 = (xx[None] - centre[:, 0, None, None]) ** 2 + (yy[None] - centre[:, 1, None, None]) ** 2
    return ~(d2 > r * r)


def _coarse_peak(t: np.ndarray, s: np.ndarray, ok: np.ndarray, f: int, kr: int,
                 kc: int) -> np.ndarray:
    """Full-resolution top-left (column, row) of the best NCC at decimation ``f``.

    The template's centre pixel and every ``f``-th pixel around it (``2 kr + 1`` rows,
    ``2 kc + 1`` columns), the chip's every ``f``-th pixel, both after a ``f x f`` box
    filter; a coarse position counts where its full-resolution top-left is ``ok``. NaN
    where no position counts.
    """
    n, th, tw = t.shape
    cr, cc = (th - 1) // 2, (tw - 1) // 2
    ts = uniform_filter(t, size=(1, f, f), mode="nearest")
    ss = uniform_filter(s, size=(1, f, f), mode="nearest")
    td = ts[:, cr - kr * f:cr + kr * f + 1:f, cc - kc * f:cc + kc * f + 1:f]
    sd = ss[:, ::f, ::f]
    rho = ncc_surface(td, sd)
    gr, gc = np.mgrid[0:rho.shape[1], 0:rho.shape[2]]
    fr, fc = f * (gr + kr) - cr, f * (gc + kc) - cc  # full top-left of the centre
    inside = (fr >= 0) & (fc >= 0) & (fr < ok.shape[1]) & (fc < ok.shape[2])
    okc = np.zeros(rho.shape, bool)
    okc[:, inside] = ok[:, fr[inside], fc[inside]]
    r = np.where(np.isfinite(rho) & okc, rho, -np.inf).reshape(n, -1)
    k = np.argmax(r, axis=1)
    found = np.isfinite(r[np.arange(n), k])
    out = np.column_stack([fc.ravel()[k], fr.ravel()[k]]).astype(float)
    return np.where(found[:, None], out, np.nan)  # NaN: no coarse peak


def sample(chips: np.ndarray, cols: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Bilinear values of chip ``i`` at ``(cols[i], rows[i])`` (any trailing shape).

    Outside a chip the value is NaN.
    """
    chips = np.asarray(chips, float)
    n = chips.shape[0]
    batch = np.arange(n).reshape((n,) + (1,) * (np.ndim(cols) - 1))
    return sample_many([chips], batch, cols, rows)[0]


def sample_many(arrays: list, batch: np.ndarray, cols: np.ndarray,
                rows: np.ndarray) -> list:
    """Bilinear values of several same-shaped chip stacks at the same positions.

    Parameters
    ----------
    arrays : list of numpy.ndarray, each shape (n, H, W)
    batch : numpy.ndarray of int
        Chip index of each position (broadcast against ``cols``).
    cols, rows : numpy.ndarray
        Positions (chip column, row); outside ``[0, W-1] x [0, H-1]`` the value is NaN.

    Returns
    -------
    list of numpy.ndarray, shape of ``cols``
    """
    n, hh, ww = arrays[0].shape
    cols = np.asarray(cols, float)
    rows = np.asarray(rows, float)
    ok = (cols >= 0) & (rows >= 0) & (cols <= ww - 1) & (rows <= hh - 1)
    c0 = np.clip(np.floor(np.where(ok, cols, 0.0)), 0, max(ww - 2, 0)).astype(np.int64)
    r0 = np.clip(np.floor(np.where(ok, rows, 0.0)), 0, max(hh - 2, 0)).astype(np.int64)
    fc = np.where(ok, cols, 0.0) - c0
    fr = np.where(ok, rows, 0.0) - r0
    base = (np.asarray(batch, np.int64) * hh + r0) * ww + c0
    step_c = 1 if ww > 1 else 0
    step_r = ww if hh > 1 else 0
    w00, w01 = (1 - fr) * (1 - fc), (1 - fr) * fc
    w10, w11 = fr * (1 - fc), fr * fc
    out = []
    for a in arrays:
        f = a.reshape(-1)
        v = (w00 * f[base] + w01 * f[base + step_c] + w10 * f[base + step_r]
             + w11 * f[base + step_r + step_c])
        out.append(np.where(ok, v, np.nan))
    return out


def _gather(stack: np.ndarray, batch: np.ndarray, cols: np.ndarray,
            rows: np.ndarray) -> tuple:
    """Bilinear values of the ``q`` layers of ``stack`` ``(n, H, W, q)`` at the positions
    (as :func:`sample_many`, NaN outside; one gather of all layers per corner)."""
    n, hh, ww, q = stack.shape
    ok = (cols >= 0) & (rows >= 0) & (cols <= ww - 1) & (rows <= hh - 1)
    c0 = np.clip(np.floor(np.where(ok, cols, 0.0)), 0, max(ww - 2, 0)).astype(np.int64)
    r0 = np.clip(np.floor(np.where(ok, rows, 0.0)), 0, max(hh - 2, 0)).astype(np.int64)
    fc = (np.where(ok, cols, 0.0) - c0)[..., None]
    fr = (np.where(ok, rows, 0.0) - r0)[..., None]
    base = (np.asarray(batch, np.int64) * hh + r0) * ww + c0
    f = stack.reshape(-1, q)
    step_c, step_r = (1 if ww > 1 else 0), (ww if hh > 1 else 0)
    v = ((1 - fr) * (1 - fc) * f[base] + (1 - fr) * fc * f[base + step_c]
         + fr * (1 - fc) * f[base + step_r] + fr * fc * f[base + step_r + step_c])
    v = np.where(ok[..., None], v, np.nan)
    return tuple(v[..., j] for j in range(q))


@dataclass
class LSMResult:
    """Least-squares matching of each template in its chip.

    Attributes
    ----------
    pos : numpy.ndarray, shape (n, 2)
        Chip (column, row) of the template centre (the shift ``t``).
    affine : numpy.ndarray, shape (n, 2, 2)
        ``A``: chip offsets per template pixel.
    radiometry : numpy.ndarray, shape (n, 2) or (n, 3)
        ``r0, r1`` (and ``r2`` with the quadratic term).
    sigma : numpy.ndarray, shape (n, 2)
        Standard deviations of ``pos`` (chip pixels) from ``sigma0^2 N^-1``.
    rho : numpy.ndarray, shape (n,)
        Correlation coefficient of the template and the matched patch.
    sigma0 : numpy.ndarray, shape (n,)
        Root mean square grey-value residual.
    converged : numpy.ndarray of bool, shape (n,)
    iterations : numpy.ndarray of int, shape (n,)
    inflation : numpy.ndarray, shape (n,)
        How much ``sigma`` understates the scatter of ``pos`` because neighbouring
        grey-value residuals are correlated (JPEG blocks, blur, resampling):
        ``sqrt((1 + rx)(1 + ry) / ((1 - rx)(1 - ry)))`` with ``rx, ry`` the lag-one
        correlations of the residuals along the columns and rows (clipped to
        ``[0, 0.9]``; 1 for white residuals), the factor by which correlated
        residuals reduce the number of independent observations.
    """

    pos: np.ndarray
    affine: np.ndarray
    radiometry: np.ndarray
    sigma: np.ndarray
    rho: np.ndarray
    sigma0: np.ndarray
    converged: np.ndarray
    iterations: np.ndarray
    inflation: np.ndarray | None = None


def _lsm_design(stack, p, u, v, scale, idx=None):
    """Model values ``(k, m)`` and design matrix ``(k, m, q)`` at parameters ``p``.

    ``stack``: each chip's grey values and their column and row gradients, shape
    ``(n, H, W, 3)`` (:func:`_gather`). ``p``: ``a11 a12 a21 a22 t_col t_row r0 r1
    [r2]``; the radiometric model is ``r0 + r1 g2 (+ r2 g2^2 / scale)``. ``idx``: the
    chips the rows of ``p`` belong to (default all).
    """
    idx = np.arange(len(p)) if idx is None else idx
    u, v, scale = u[:1], v[:1], scale[idx]
    cols = p[:, 4, None] + p[:, 0, None] * u + p[:, 1, None] * v
    rows = p[:, 5, None] + p[:, 2, None] * u + p[:, 3, None] * v
    g2, gx, gy = _gather(stack, idx[:, None], cols, rows)
    quad = p.shape[1] == 9
    r1 = p[:, 7, None] + (2.0 * p[:, 8, None] * g2 / scale[:, None] if quad else 0.0)
    colsd = [r1 * gx * u, r1 * gx * v, r1 * gy * u, r1 * gy * v, r1 * gx, r1 * gy,
             np.ones_like(g2), g2]
    model = p[:, 6, None] + p[:, 7, None] * g2
    if quad:
        colsd.append(g2 * g2 / scale[:, None])
        model = model + p[:, 8, None] * colsd[-1]
    return model, g2, np.stack(colsd, axis=-1)


def lsm(templates: np.ndarray, chips: np.ndarray, start: np.ndarray,
        affine0: np.ndarray | None = None, max_iterations: int = 40,
        tol: float = 0.005, quadratic: bool = False,
        sigma0_floor: float = 0.0, tol_sigma: float = 0.0) -> LSMResult:
    """Least-squares matching with an affine patch and linear radiometry (Gruen 1985).

    Parameters
    ----------
    templates : numpy.ndarray, shape (n, th, tw)
        Reference patches; ``(u, v)`` are pixel offsets from the middle pixel.
    chips : numpy.ndarray, shape (n, H, W)
        Search chips.
    start : numpy.ndarray, shape (n, 2)
        Approximate chip (column, row) of the template centre (e.g. from NCC).
    affine0 : numpy.ndarray, shape (n, 2, 2), optional
        Approximate ``A`` (default the identity), e.g. from the image geometry.
    max_iterations : int
    tol : float
        Convergence: the largest change of a patch corner's position below ``tol`` px.
    quadratic : bool
        Add a quadratic radiometric term ``r2 g2^2`` (a gamma difference between the
        images); 9 parameters instead of 8.
    sigma0_floor : float
        Smallest grey-value residual RMS used for the precision (e.g. the quantisation
        ``step / sqrt(12)`` of the grey values): two identical patches (a flat JPEG
        block on both images) fit without residuals, which does not make their
        position exact.

    Returns
    -------
    LSMResult
        ``sigma`` is ``max(sigma0, sigma0_floor)^2 N^-1`` (scaled by the residuals,
        never 0 when ``sigma0_floor > 0``). Points whose patch leaves the chip, whose
        normal matrix is singular or that have not converged in ``max_iterations``
        have ``converged = False``.
    """
    t = np.asarray(templates, float)
    s = np.asarray(chips, float)
    n, th, tw = t.shape
    vv, uu = np.mgrid[0:th, 0:tw]
    u = (uu - (tw - 1) / 2.0).ravel()[None, :].repeat(n, 0)
    v = (vv - (th - 1) / 2.0).ravel()[None, :].repeat(n, 0)
    g1 = t.reshape(n, -1)
    grads = np.gradient(s, axis=(1, 2))
    stack = np.stack([s, grads[1], grads[0]], axis=-1)  # grey, d/dcolumn, d/drow
    scale = np.fmax.reduce(np.abs(s).reshape(n, s[0].size if n else 0), axis=1,
                           initial=np.nan) + 1e-12  # a chip all NaN: NaN, no warning
    p = np.zeros((n, 9 if quadratic else 8))
    a0 = np.broadcast_to(np.eye(2), (n, 2, 2)) if affine0 is None else np.asarray(affine0, float)
    p[:, :4] = a0.reshape(n, 4)
    p[:, 4:6] = np.asarray(start, float)
    _, g2, _ = _lsm_design(stack, p, u, v, scale)
    p[:, 7], p[:, 6] = _linear_fit(g2, g1)
    active = np.ones(n, bool)
    done = np.zeros(n, bool)
    its = np.zeros(n, int)
    corner = np.array([(tw - 1) / 2.0, (th - 1) / 2.0])
    last = np.full(n, np.inf)
    for _ in range(max_iterations):
        ia = np.flatnonzero(active)
        if ia.size == 0:
            break
        model, g2, a = _lsm_design(stack, p[ia], u, v, scale, ia)
        bad = ~np.all(np.isfinite(a), axis=(1, 2)) | ~np.all(np.isfinite(g2), axis=1)
        active[ia[bad]] = False
        ok = ~bad
        ia, a, l = ia[ok], a[ok], (g1[ia] - model)[ok]
        dp = _solve(a, np.where(np.isfinite(l), l, 0.0), np.ones(len(ia), bool))
        p[ia] += np.nan_to_num(dp)
        its[ia] += 1
        move = np.abs(dp[:, 4:6]).max(axis=1) + np.abs(dp[:, :4]).max(axis=1) * corner.max()
        last[ia] = move
        fin = move < tol
        done[ia[fin]] = True
        active[ia[fin | ~np.isfinite(move)]] = False
    out = _lsm_result(stack, p, u, v, g1, done | active, its, scale, sigma0_floor, (th, tw))
    steady = active & (last < tol_sigma * np.nanmax(np.nan_to_num(out.sigma, nan=-1.0), axis=1))
    out.converged &= done | steady
    out.sigma = np.where(out.converged[:, None], out.sigma, np.nan)
    return out


def _linear_fit(x: np.ndarray, y: np.ndarray):
    """Gain and offset of ``y ~ r0 + r1 x`` per row (NaN-safe)."""
    x = np.where(np.isfinite(x), x, 0.0)
    xm = x.mean(axis=1, keepdims=True)
    ym = y.mean(axis=1, keepdims=True)
    sxx = np.sum((x - xm) ** 2, axis=1)
    r1 = np.where(sxx > 0, np.sum((x - xm) * (y - ym), axis=1) / np.where(sxx > 0, sxx, 1), 1.0)
    return r1, ym[:, 0] - r1 * xm[:, 0]


def _solve(a: np.ndarray, l: np.ndarray, active: np.ndarray) -> np.ndarray:
    """Gauss-Newton steps of the active rows (zero elsewhere, and where N is singular)."""
    n, k = len(a), a.shape[-1]
    out = np.zeros((n, k))
    idx = np.flatnonzero(active)
    if idx.size == 0:
        return out
    at = np.swapaxes(a[idx], 1, 2)
    nn = at @ a[idx]  # batched BLAS: much faster than einsum for (n, m, 9)
    b = (at @ l[idx][:, :, None])[:, :, 0]
    out[idx] = batched_solve(nn, b)
    return out


def batched_solve(m: np.ndarray, b: np.ndarray, rcond: float = 1e-13) -> np.ndarray:
    """Solve many small symmetric positive systems ``m x = b`` at once (Gauss-Jordan).

    Vectorised over the batch (a loop over the ``k`` unknowns only), which for thousands of
    9 x 9 systems is much faster than LAPACK called once per matrix. Rows whose pivot
    falls below ``rcond`` times the largest diagonal element (a singular system) get NaN.

    Parameters
    ----------
    m : numpy.ndarray, shape (n, k, k)
    b : numpy.ndarray, shape (n, k)

    Returns
    -------
    numpy.ndarray, shape (n, k)
    """
    a = np.concatenate([np.array(m, float), np.asarray(b, float)[..., None]], axis=2)
    n, k = a.shape[:2]
    scale = np.abs(np.diagonal(a[:, :, :k], axis1=1, axis2=2)).max(axis=1) + 1e-300
    bad = np.zeros(n, bool)
    rows = np.arange(n)
    for j in range(k):
        piv = j + np.argmax(np.abs(a[:, j:, j]), axis=1)
        tmp = a[rows, piv].copy()
        a[rows, piv] = a[:, j]
        a[:, j] = tmp
        p = a[:, j, j]
        bad |= ~(np.abs(p) > rcond * scale)
        a[:, j] /= np.where(bad, 1.0, p)[:, None]
        f = a[:, :, j].copy()
        f[:, j] = 0.0
        a -= f[:, :, None] * a[:, j][:, None, :]
    x = a[:, :, k]
    x[bad] = np.nan
    return x


def _lsm_result(stack, p, u, v, g1, done, its, scale, floor=0.0,
                shape=(1, -1)) -> LSMResult:
    """Precision, correlation coefficient and residual inflation at the final parameters
    (``shape``: the template's rows and columns)."""
    n, k = p.shape
    model, g2, a = _lsm_design(stack, p, u, v, scale)
    finite = np.all(np.isfinite(a), axis=(1, 2)) & np.all(np.isfinite(g2), axis=1)
    a = np.where(finite[:, None, None], a, 0.0)
    g2 = np.where(finite[:, None], g2, 0.0)
    res = np.where(finite[:, None], g1 - model, 0.0)
    m = g1.shape[1]
    s0sq = np.sum(res * res, axis=1) / max(m - k, 1)
    s0_used = np.maximum(s0sq, float(floor) ** 2)
    nn = np.swapaxes(a, 1, 2) @ a + np.eye(k) * 1e-12
    e4 = np.zeros((n, k))
    e4[:, 4] = 1.0
    e5 = np.zeros((n, k))
    e5[:, 5] = 1.0
    q4, q5 = batched_solve(nn, e4), batched_solve(nn, e5)
    qq = np.stack([q4[:, 4], q5[:, 4 + 1]], axis=1)
    sig = np.sqrt(np.clip(s0_used[:, None] * qq, 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = np.array([np.nan] * n) if n == 0 else _rowcorr(g1, g2)
    conv = done & finite
    sig = np.where(conv[:, None], sig, np.nan)
    w = np.swapaxes(a @ np.nan_to_num(np.stack([q4, q5], axis=2)), 1, 2)  # (n, 2, m)
    infl = residual_inflation(res.reshape((n,) + tuple(shape)),
                              w.reshape((n, 2) + tuple(shape)))
    return LSMResult(p[:, 4:6].copy(), p[:, :4].reshape(n, 2, 2), p[:, 6:].copy(), sig,
                     np.where(finite, rho, np.nan), np.sqrt(s0sq), conv, its, infl)


def residual_inflation(res: np.ndarray, weights: np.ndarray, lags: int = 3) -> np.ndarray:
    """How much correlated residuals widen a least-squares shift's standard deviation.

    The LSM sigma ``sigma0^2 N^-1`` assumes independent grey-value residuals; those of a
    compressed, blurred or resampled image are correlated over a few pixels. The shift is
    ``t = sum_i w_i l_i`` (``w``: its row of ``N^-1 A'``), so its variance is
    ``sum_d gamma(d) sum_i w_i w_(i+d)`` over the lags ``d`` of the residuals'
    autocovariance ``gamma`` (a kernel estimate of the sandwich covariance with
    Bartlett weights up to ``lags`` pixels in each direction, which keeps it positive);
    the ratio to the lag-0 term ``gamma(0) sum w_i^2`` is the inflation.

    Parameters
    ----------
    res : numpy.ndarray, shape (n, rows, columns)
        Grey-value residuals of each patch.
    weights : numpy.ndarray, shape (n, 2, rows, columns)
        Each shift's (column, row) weights ``w`` of the observations.
    lags : int
        Largest lag (pixels) of the autocovariance.

    Returns
    -------
    numpy.ndarray, shape (n,)
        The square root of the ratio, of the worse axis; at least 1 (1 where undefined,
        e.g. no residuals).
    """
    e = np.asarray(res, float)
    w = np.asarray(weights, float)
    _, th, tw = e.shape
    e = e - e.mean(axis=(1, 2), keepdims=True)
    gamma = _autocorrelation(e, lags) / (th * tw)  # (n, 2 lags + 1, 2 lags + 1)
    sw = _autocorrelation(w, lags)  # (n, 2, 2 lags + 1, 2 lags + 1)
    tri = 1 - np.abs(np.arange(-lags, lags + 1)) / (lags + 1)
    kern = tri[:, None] * tri[None, :]  # Bartlett weights
    num = np.sum(kern * gamma[:, None] * sw, axis=(2, 3))
    den = gamma[:, None, lags, lags] * sw[:, :, lags, lags]
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.max(num / den, axis=1)
    return np.sqrt(np.where(np.isfinite(ratio), np.maximum(ratio, 1.0), 1.0))


def _autocorrelation(x: np.ndarray, lags: int) -> np.ndarray:
    """``sum_i x_i x_(i+d)`` over the last two axes for every lag ``d`` up to ``lags``
    in each direction, shape ``(..., 2 lags + 1, 2 lags + 1)`` (lag 0 in the middle);
    by FFT, zero-padded so that no lag wraps around."""
    th, tw = x.shape[-2:]
    shape = [sfft.next_fast_len(v + lags, real=True) for v in (th, tw)]
    f = sfft.rfft2(x, shape, axes=(-2, -1))
    a = sfft.irfft2(f * f.conj(), shape, axes=(-2, -1))
    k = np.arange(-lags, lags + 1)
    return a[..., (k % shape[0])[:, None], (k % shape[1])[None, :]]


def _rowcorr(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    xz = x - x.mean(axis=1, keepdims=True)
    yz = y - y.mean(axis=1, keepdims=True)
    return np.sum(xz * yz, axis=1) / np.sqrt(np.sum(xz * xz, axis=1) * np.sum(yz * yz, axis=1))


def texture_measures(chips: np.ndarray, origin: np.ndarray, centre: np.ndarray, half: int,
                     block: int = 8) -> dict:
    """How much real texture the ``2 half + 1`` square around each centre holds.

    Computed on the image's own pixels (no resampling), so that the block structure of
    a JPEG image lines up with the image's 8 x 8 grid.

    Parameters
    ----------
    chips : numpy.ndarray, shape (n, H, W)
        Image chips (NaN outside the image).
    origin : numpy.ndarray, shape (n, 2)
        Image array (column, row) of each chip's element ``[0, 0]`` (integers).
    centre : numpy.ndarray, shape (n, 2)
        Image array (column, row) of each template centre (rounded here).
    half : int
        Template half size.
    block : int
        Side of the compression blocks (8 for JPEG).

    Returns
    -------
    dict of numpy.ndarray, shape (n,)
        ``levels``: distinct grey values (to 0.01); ``entropy``: Shannon entropy (bits)
        of the grey values in 32 bins between their 1st and 99th percentiles;
        ``blockiness``: mean absolute grey difference across the ``block`` grid's lines
        over that inside the blocks (about 1 for natural texture, large for flat JPEG
        blocks); ``roundness``: Foerstner's ``q = 4 det N / trace(N)^2`` of the whole
        window's structure tensor ``N`` (0 for a straight edge or stripe, 1 isotropic);
        ``weight``: ``det N / trace N`` per pixel (grey^2 / px^2).
    """
    a = np.asarray(chips, float)
    n = len(a)
    size = 2 * half + 1
    loc = np.round(np.asarray(centre, float) - np.asarray(origin, float)).astype(np.int64)
    off = np.arange(size) - half
    rr = np.clip(loc[:, 1, None] + off, 0, a.shape[1] - 1)
    cc = np.clip(loc[:, 0, None] + off, 0, a.shape[2] - 1)
    w = a[np.arange(n)[:, None, None], rr[:, :, None], cc[:, None, :]]
    w = np.where(np.isfinite(w), w, np.nanmean(w) if np.isfinite(w).any() else 0.0)
    flat = w.reshape(n, -1)
    levels = np.array([np.unique(np.round(f, 2)).size for f in flat])
    lo, hi = np.percentile(flat, [1, 99], axis=1)
    span = np.where(hi > lo, hi - lo, 1.0)
    idx = np.clip(((flat - lo[:, None]) / span[:, None] * 32).astype(np.int64), 0, 31)
    counts = np.zeros((n, 32))
    np.add.at(counts, (np.arange(n)[:, None], idx), 1.0)
    pr = counts / flat.shape[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        entropy = -np.sum(np.where(pr > 0, pr * np.log2(pr), 0.0), axis=1)
    entropy = np.where(hi > lo, entropy, 0.0)
    img0 = np.asarray(origin, np.int64) + loc - half  # image index of w[:, 0, 0]
    blockiness = _blockiness(w, img0, block)
    gy, gx = np.gradient(w, axis=(1, 2))
    nxx, nyy, nxy = (np.mean(v, axis=(1, 2)) for v in (gx * gx, gy * gy, gx * gy))
    det, tr = nxx * nyy - nxy * nxy, nxx + nyy
    with np.errstate(divide="ignore", invalid="ignore"):
        roundness = np.where(tr > 0, 4.0 * det / (tr * tr), 0.0)
        weight = np.where(tr > 0, det / tr, 0.0)
    return {"levels": levels, "entropy": entropy, "blockiness": blockiness,
            "roundness": roundness, "weight": weight}


def _blockiness(w: np.ndarray, img0: np.ndarray, block: int) -> np.ndarray:
    """Mean |difference| across the block grid's lines / inside the blocks, per window."""
    n, size = w.shape[0], w.shape[1]
    dx = np.abs(np.diff(w, axis=2))  # between columns j and j + 1
    dy = np.abs(np.diff(w, axis=1))
    j = np.arange(size - 1)
    on_c = (img0[:, 0, None] + j + 1) % block == 0  # (n, size - 1)
    on_r = (img0[:, 1, None] + j + 1) % block == 0
    mx = dx.mean(axis=1)  # (n, size - 1) mean over rows
    my = dy.mean(axis=2)
    cross = np.sum(mx * on_c, axis=1) + np.sum(my * on_r, axis=1)
    n_cross = on_c.sum(axis=1) + on_r.sum(axis=1)
    inner = np.sum(mx * ~on_c, axis=1) + np.sum(my * ~on_r, axis=1)
    n_inner = (~on_c).sum(axis=1) + (~on_r).sum(axis=1)
    ci = cross / np.maximum(n_cross, 1)
    ii = inner / np.maximum(n_inner, 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(ii > 0, ci / ii, np.where(ci > 0, np.inf, 1.0))
    return out if n else np.zeros(0)

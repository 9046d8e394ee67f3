"""Transfer of points between images: prediction, NCC search, LSM refinement, flags.

:func:`match_batch` finds ``n`` points of a reference image on a target image. For
each point the caller gives a chip of each image (read around the reference position and
the predicted target position), the local affine between the images over the terrain
(:func:`vectoradjust.measure.geometry.local_affine`) and the covariance of the
prediction. The reference patch is correlated with the target chip resampled into the
reference geometry (so rotation, scale and relief displacement between the images do
not spoil the correlation), the best position inside the search ellipse - found
coarse-to-fine over an image pyramid - is refined by least-squares matching, and every
failure is flagged (:data:`matching.FLAGS`): a flagged
match is never accepted.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vectoradjust.measure.geometry import WINDOW_K, inv2, window_axes
from vectoradjust.measure.matching import FLAGS, lsm, ncc_pyramid, sample, texture_measures

__all__ = ["MatchSettings", "MatchResult", "match_batch"]


@dataclass
class MatchResult:
    """Matched target pixels and their quality.

    Attributes
    ----------
    px : numpy.ndarray, shape (n, 2)
        Target image (column, row) from LSM (NaN where LSM failed).
    ncc : numpy.ndarray, shape (n,)
        NCC coefficient at the approximate position.
    rho : numpy.ndarray, shape (n,)
        Correlation coefficient after LSM.
    sigma : numpy.ndarray, shape (n, 2)
        LSM standard deviations (target pixels).
    flags : numpy.ndarray of int, shape (n,)
        Bits of :data:`matching.FLAGS`; 0 = accepted.
    texture : dict of numpy.ndarray, shape (n,)
        The reference templates' texture measures
        (:func:`~vectoradjust.measure.matching.texture_measures`).
    inflation : numpy.ndarray, shape (n,)
        Factor by which ``sigma`` understates the scatter because the LSM residuals are
        correlated (:func:`~vectoradjust.measure.matching.residual_inflation`).
    """

    px: np.ndarray
    ncc: np.ndarray
    rho: np.ndarray
    sigma: np.ndarray
    flags: np.ndarray
    texture: dict = field(default_factory=dict)
    inflation: np.ndarray | None = None

    @property
    def accepted(self) -> np.ndarray:
        """Matches without any flag."""
        return self.flags == 0


@dataclass
class MatchSettings:
    """Thresholds of automatic transfer, in the order the matching uses them.

    Each is a flag of ``vectoradjust measure transfer`` (``--half-template``,
    ``--min-grey-levels``, ...; ``k`` is ``--window-k``, ``quadratic`` ``--quadratic`` /
    ``--no-quadratic``) whose help is the description below.

    Attributes
    ----------
    half_template : int
        Template half size (pixels of the reference image); the template is
        ``2 h + 1`` square.
    retry_template : float
        A transfer rejected only for precision, texture or ambiguity
        (``poor_precision``, ``no_texture``, ``ambiguous``) is matched again - with
        every check, back-matching included - with a template this many times larger
        (``round(retry_template h)``), and the retry replaces it where it is accepted
        (1: no retry). On compressed images the residuals of a 41 px template are
        correlated within the 8 x 8 JPEG blocks, so its LSM precision often fails the
        threshold on good texture; a larger template averages more blocks (rendered
        pairs at JPEG quality 30), while the first, smaller template keeps relief and
        occlusions (real aerial frames) from spoiling the rest.
    min_grey_levels : int
        Fewest distinct grey values in the reference template (a flat JPEG block holds
        two or three).
    min_entropy : float
        Smallest entropy (bits, 32 bins) of the template's grey values.
    max_blockiness : float
        Largest ratio of the grey differences across the 8 x 8 JPEG block lines to
        those inside the blocks (natural texture about 1, flat JPEG blocks far above).
    min_roundness : float
        Smallest Foerstner roundness of the template (0: a straight edge or stripe).
        These four reject the template as ``no_texture``
        (:func:`~vectoradjust.measure.matching.texture_measures`).
    max_radius : float
        Largest search radius (pixels of the reference geometry); a larger window is
        clipped to it.
    k : float
        Scale of the search ellipse in standard deviations of the prediction (the
        default holds 99.9 % of a normal distribution in two dimensions).
    pyramid_levels : int
        Coarse-to-fine search (:func:`~vectoradjust.measure.matching.ncc_pyramid`):
        the peak is found at ``1 / 2^pyramid_levels`` of the resolution in the whole
        window and followed down, each finer level searching only near the coarser
        peak (0: the best full-resolution NCC of the whole window).
    pyramid_radius : float
        Search radius around a coarser level's peak (pixels of that level).
    min_ncc : float
        Correlation coefficient threshold (0.8 - 0.95 in production) for NCC and LSM.
    distinct_factor : float
        A match whose NCC peak is distinct (every other peak of the window at least
        ``distinct_gap`` lower) may be ``distinct_factor`` times as far from a perfect
        correlation: accepted down to ``1 - distinct_factor (1 - min_ncc)`` (NCC and
        LSM; 0.6 for ``min_ncc`` 0.8). ``1 - rho`` is about the share of noise in the
        grey-value variance, so this admits about twice the noise where the peak is
        unique: on compressed images with relief the correlation of a true match drops,
        but a clear, unique peak is still the right one (1: ``min_ncc`` for all).
    distinct_gap : float
        How much lower than the peak every other peak must be for ``distinct_factor``.
    ambiguity : float
        A second NCC peak within this of the first flags the match as ambiguous.
    quadratic : bool
        LSM with a quadratic radiometric term (images with different gamma).
    grey_step : float
        Resolution of the grey values (1 for 8-bit images): the LSM residual RMS is
        taken as at least ``grey_step / sqrt(12)`` (quantisation).
    lsm_tol_sigma : float
        LSM still moving after its iterations is converged when its last step is below
        this fraction of its own standard deviation (noisy images; 0: off;
        :func:`~vectoradjust.measure.matching.lsm`).
    max_lsm_move : float
        Largest accepted distance between the NCC and the LSM positions (pixels).
    max_sigma : float
        Largest accepted LSM standard deviation of the position (pixels).
    min_sigma : float
        Floor of the reported LSM sigma (px): a precision is never 0.
    max_anisotropy : float
        Largest ratio of the LSM sigmas of the two axes (above ``max_sigma / 3``): a
        patch textured in one direction only (an edge, a road) slides along it
        (``inf``: off).
    back_tolerance : float
        Largest distance (px) between the reference point and the target match
        matched back to the reference image (``inf``: no back-matching). With
        ``back_k`` the smallest tolerance: noisier matches get ``back_k`` times the
        standard deviation of the back-match's distance, up to twice ``back_tolerance``
        (:func:`vectoradjust.files.measuring.back_tolerance`).
    back_k : float
        Tolerance of the back-matching in standard deviations of its distance (from
        the LSM sigmas inflated for correlated residuals; 0: ``back_tolerance``
        alone).
    max_ray_misfit : float
        A point accepted on three or more frame images: the forward intersection of
        all its rays must reproduce each match within about this many pixels (more
        where the orientations are uncertain; ``inf``: no check); else flag
        ``inconsistent`` (:func:`vectoradjust.files.measuring.transfer`).
    """

    half_template: int = 20
    retry_template: float = 1.5
    min_grey_levels: int = 8
    min_entropy: float = 2.5
    max_blockiness: float = 5.0
    min_roundness: float = 0.1
    max_radius: float = 40.0
    k: float = WINDOW_K
    pyramid_levels: int = 2
    pyramid_radius: float = 1.5
    min_ncc: float = 0.8
    distinct_factor: float = 2.0
    distinct_gap: float = 0.1
    ambiguity: float = 0.02
    quadratic: bool = True
    grey_step: float = 1.0
    lsm_tol_sigma: float = 0.2
    max_lsm_move: float = 1.5
    max_sigma: float = 0.07
    min_sigma: float = 0.01
    max_anisotropy: float = 5.0
    back_tolerance: float = 0.5
    back_k: float = 3.0
    max_ray_misfit: float = 1.0


def match_batch(ref_chips: np.ndarray, ref_origin: np.ndarray, ref_px: np.ndarray,
                tgt_chips: np.ndarray, tgt_origin: np.ndarray, pred_px: np.ndarray,
                affine: np.ndarray, cov: np.ndarray,
                settings: MatchSettings | None = None) -> MatchResult:
    """Find reference points on a target image.

    Parameters
    ----------
    ref_chips : numpy.ndarray, shape (n, Hr, Wr)
        Reference image chips (NaN outside the image).
    ref_origin : numpy.ndarray, shape (n, 2)
        Image (column, row) of each reference chip's pixel (0, 0).
    ref_px : numpy.ndarray, shape (n, 2)
        Reference image (column, row) of the points.
    tgt_chips : numpy.ndarray, shape (n, Ht, Wt)
        Target image chips around the predictions.
    tgt_origin : numpy.ndarray, shape (n, 2)
    pred_px : numpy.ndarray, shape (n, 2)
        Predicted target (column, row).
    affine : numpy.ndarray, shape (n, 2, 2)
        ``d target / d reference`` at the points.
    cov : numpy.ndarray, shape (n, 2, 2)
        Covariance of the prediction (target pixels^2).
    settings : MatchSettings, optional

    Returns
    -------
    MatchResult
    """
    st = settings or MatchSettings()
    h = int(st.half_template)
    n = len(ref_px)
    off = np.arange(-h, h + 1, dtype=float)
    vv, uu = np.meshgrid(off, off, indexing="ij")
    rloc = np.asarray(ref_px, float) - np.asarray(ref_origin, float)
    templ = sample(ref_chips, rloc[:, 0, None, None] + uu, rloc[:, 1, None, None] + vv)
    flags = np.zeros(n, np.int64)
    flags[~np.all(np.isfinite(templ), axis=(1, 2))] |= FLAGS["edge"]
    templ = np.where(np.isfinite(templ), templ, np.nanmean(templ) if np.isfinite(templ).any()
                     else 0.0)
    spread = templ.std(axis=(1, 2))
    flags[spread < 1e-6 * (np.abs(templ).max(axis=(1, 2)) + 1e-12)] |= FLAGS["no_texture"]
    tex = texture_measures(ref_chips, ref_origin, ref_px, h)
    flags[_poor_texture(tex, st)] |= FLAGS["no_texture"]

    rad = int(np.ceil(st.max_radius))
    soff = np.arange(-(h + rad), h + rad + 1, dtype=float)
    sv, su = np.meshgrid(soff, soff, indexing="ij")
    a = np.asarray(affine, float)
    ploc = np.asarray(pred_px, float) - np.asarray(tgt_origin, float)
    wc = ploc[:, 0, None, None] + a[:, 0, 0, None, None] * su + a[:, 0, 1, None, None] * sv
    wr = ploc[:, 1, None, None] + a[:, 1, 0, None, None] * su + a[:, 1, 1, None, None] * sv
    warped = sample(tgt_chips, wc, wr)
    seen = np.isfinite(warped)
    fill = np.where(seen, warped, 0.0).sum(axis=(1, 2)) / np.maximum(seen.sum(axis=(1, 2)), 1)
    warped = np.where(seen, warped, fill[:, None, None])

    dr = np.arange(-rad, rad + 1, dtype=float)
    dv, du = np.meshgrid(dr, dr, indexing="ij")
    allowed = _in_ellipse(a, cov, du, dv, st.k) & (du**2 + dv**2 <= st.max_radius**2)
    nc = ncc_pyramid(templ, warped, allowed, st.pyramid_levels, st.pyramid_radius)
    d = nc.pos - (h + rad)
    approx = np.asarray(pred_px, float) + np.einsum("nij,nj->ni", a, d)
    res = lsm(templ, tgt_chips, approx - np.asarray(tgt_origin, float), a,
              quadratic=st.quadratic, sigma0_floor=st.grey_step / np.sqrt(12.0),
              tol_sigma=st.lsm_tol_sigma)
    res.sigma = np.maximum(res.sigma, st.min_sigma)
    px = res.pos + np.asarray(tgt_origin, float)
    flags |= _quality_flags(nc, res, px, approx, np.asarray(pred_px, float), cov, st)
    ai = inv2(a)
    cov_ref = ai @ np.asarray(cov, float) @ np.swapaxes(ai, 1, 2)
    flags[window_axes(cov_ref, st.k)[:, 0] > st.max_radius] |= FLAGS["window_clipped"]
    px = np.where(res.converged[:, None], px, np.nan)
    return MatchResult(px, nc.ncc, res.rho, res.sigma, flags, tex, res.inflation)


def _poor_texture(tex: dict, st: MatchSettings) -> np.ndarray:
    """Templates without real texture: few grey levels, low entropy, JPEG blocks, a
    straight edge or stripe."""
    return ((tex["levels"] < st.min_grey_levels) | (tex["entropy"] < st.min_entropy)
            | (tex["blockiness"] > st.max_blockiness) | (tex["roundness"] < st.min_roundness))


def _in_ellipse(a, cov, du, dv, k):
    """Reference-geometry offsets whose target offset ``A d`` lies in the ellipse."""
    c = np.asarray(cov, float) + (0.5**2 / k**2) * np.eye(2)
    ci = inv2(c)
    tx = a[:, 0, 0, None, None] * du + a[:, 0, 1, None, None] * dv
    ty = a[:, 1, 0, None, None] * du + a[:, 1, 1, None, None] * dv
    m = (ci[:, 0, 0, None, None] * tx * tx + 2 * ci[:, 0, 1, None, None] * tx * ty
         + ci[:, 1, 1, None, None] * ty * ty)
    return m <= k * k


def _quality_flags(nc, res, px, approx, pred, cov, st: MatchSettings) -> np.ndarray:
    """Flags from the NCC peak, the LSM solution and the search window."""
    n = len(px)
    f = np.zeros(n, np.int64)
    rho = np.where(np.isfinite(res.rho), res.rho, -1.0)
    distinct = nc.second <= nc.ncc - st.distinct_gap
    lo = np.where(distinct, 1.0 - max(st.distinct_factor, 1.0) * (1.0 - st.min_ncc), st.min_ncc)
    f[(nc.ncc < lo) | (rho < lo)] |= FLAGS["low_correlation"]
    f[nc.second >= nc.ncc - st.ambiguity] |= FLAGS["ambiguous"]
    moved = np.hypot(*(px - approx).T)
    bad = ~res.converged | ~np.isfinite(moved) | (moved > st.max_lsm_move)
    f[bad] |= FLAGS["not_converged"]
    s_all = np.where(np.isfinite(res.sigma), res.sigma, np.inf)
    sig, smin = s_all.max(axis=1), s_all.min(axis=1)
    aniso = (sig > st.max_sigma / 3.0) & (sig > st.max_anisotropy * smin)
    f[~bad & ((sig > st.max_sigma) | aniso)] |= FLAGS["poor_precision"]
    c = np.asarray(cov, float) + (0.5**2 / st.k**2) * np.eye(2)
    d = np.where(np.isfinite(px), px - pred, 0.0)
    m = np.einsum("ni,nij,nj->n", d, inv2(c), d)
    out = m > st.k**2
    f[out & ~bad] |= FLAGS["outside_window"]
    return f

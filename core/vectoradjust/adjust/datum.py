"""The datum: what fixes the block in space, checked before the solve; the free network.

The image observations of frame cameras do not change when the whole block - every
object point and every camera - is moved by a 3D similarity: three shifts, three
rotations and a scale, the seven datum parameters. Only prior information fixes them:
control points, camera position and attitude priors (GNSS/INS, EXIF GPS), the
coordinates of a road database (less what its freely estimated offset absorbs: a
database cannot fix a shift it is allowed to have), heights from a DEM.
:func:`analyse_datum` projects that prior information onto the seven parameters,
``H = G' P G - A C^-1 A'`` (``G`` the similarity's effect on every parameter, ``P`` the
prior weights, the second term the share the databases' offsets take), and reads from
its eigenvalues which parameters are determined and how well (sigma in metres at the
block's extent). :func:`check_datum` turns a missing parameter into a message that says
what would fix it - before the solve, instead of a singular matrix or absurd sigmas.

A free network (no prior at all) is adjusted with inner constraints over the cameras:
the reduced camera system ``S`` (singular along the cameras' part ``G_e`` of the seven
transformations) is solved as ``(S + a G G')^-1`` and its pseudo-inverse is
``(S + a G G')^-1 - G (G'G)^-2 G' / a`` (in the metric that counts an attitude angle
times the block's extent as metres), so the corrections keep the approximate
orientation's centroid, rotation and scale (:func:`camera_helmert`,
:func:`free_network_correction`). Its precision is relative: shapes, angles and ratios
of distances are datum-free; positions, heights and the scale come from the
approximate values. Numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from vectoradjust.errors import DatumError
from vectoradjust.sensor.collinearity import rotation_matrix, rotation_to_angles

__all__ = ["DATUM_PARAMETERS", "DatumAnalysis", "block_frame", "camera_helmert",
           "point_helmert", "datum_information", "analyse_datum", "check_datum",
           "free_network_correction", "FREE_NETWORK_NOTE"]

#: the seven datum parameters (order of every 7-vector here)
DATUM_PARAMETERS = ("X shift", "Y shift", "Z shift", "rotation about X", "rotation about Y",
                    "rotation about Z", "scale")

#: what summary.json and the report say of a free network's precision
FREE_NETWORK_NOTE = (
    "free network (inner constraints on the approximate camera orientation): no control, "
    "no priors; the precision is relative - shapes, angles and ratios of distances are "
    "datum-free, absolute positions, heights and the scale are those of the approximate "
    "values and not determined")

#: an eigenvalue of the datum information below this share of the largest (or a sigma
#: above :data:`_SIGMA_UNDETERMINED` m or the block's extent) is a datum defect
_RELATIVE_DEFECT = 1e-10
_SIGMA_UNDETERMINED = 1e6


def block_frame(eo: np.ndarray, xyz: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and extent (RMS distance from the centre, m) of cameras and points.

    Parameters
    ----------
    eo : numpy.ndarray, shape (n, 6)
    xyz : numpy.ndarray, shape (m, 3)

    Returns
    -------
    center : numpy.ndarray, shape (3,)
    extent : float
        At least 1 m.
    """
    pos = np.concatenate([np.asarray(eo, float)[:, :3], np.asarray(xyz, float).reshape(-1, 3)])
    pos = pos[np.isfinite(pos).all(axis=1)]
    if not len(pos):
        return np.zeros(3), 1.0
    center = pos.mean(axis=0)
    extent = float(np.sqrt(((pos - center) ** 2).sum(axis=1).mean()))
    return center, max(extent, 1.0)


def point_helmert(xyz: np.ndarray, center: np.ndarray, extent: float) -> np.ndarray:
    """How the seven datum parameters move points: ``(m, 3, 7)``.

    Shifts in m; a rotation or scale parameter of 1 moves a point at the distance
    ``extent`` from ``center`` by about 1 m (angle = parameter / extent).

    Examples
    --------
    >>> import numpy as np
    >>> g = point_helmert(np.array([[10.0, 0.0, 0.0]]), np.zeros(3), 10.0)
    >>> g[0, :, 5] + 0.0      # a turn about Z moves a point on the X axis along Y
    array([0., 1., 0.])
    """
    d = np.asarray(xyz, float).reshape(-1, 3) - center
    g = np.zeros((len(d), 3, 7))
    g[:, [0, 1, 2], [0, 1, 2]] = 1.0
    x, y, z = d[:, 0] / extent, d[:, 1] / extent, d[:, 2] / extent
    g[:, 1, 3], g[:, 2, 3] = -z, y  # about X: (0, -z, y)
    g[:, 0, 4], g[:, 2, 4] = z, -x  # about Y: (z, 0, -x)
    g[:, 0, 5], g[:, 1, 5] = -y, x  # about Z: (-y, x, 0)
    g[:, :, 6] = d / extent
    return g


def _skew(a: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def camera_helmert(eo: np.ndarray, center: np.ndarray, extent: float) -> np.ndarray:
    """How the seven datum parameters change the exterior orientation: ``(n, 6, 7)``.

    Positions move as points do (:func:`point_helmert`); a rotation ``R`` of the object
    space turns the ground-to-image matrix ``M`` into ``M R'``, whose angles are
    differentiated numerically (central differences).
    """
    eo = np.asarray(eo, float).reshape(-1, 6)
    g = np.zeros((len(eo), 6, 7))
    g[:, :3, :] = point_helmert(eo[:, :3], center, extent)
    m0 = rotation_matrix(eo[:, 3], eo[:, 4], eo[:, 5])
    h = 1e-6
    for axis in range(3):
        a = np.zeros(3)
        a[axis] = h
        rp = np.eye(3) + _skew(a) + _skew(a) @ _skew(a) / 2.0
        rm = np.eye(3) - _skew(a) + _skew(a) @ _skew(a) / 2.0
        d = rotation_to_angles(m0 @ rp.T) - rotation_to_angles(m0 @ rm.T)
        d = (d + np.pi) % (2.0 * np.pi) - np.pi
        g[:, 3:, 3 + axis] = d / (2.0 * h) / extent
    return g


def datum_information(eo: np.ndarray, xyz: np.ndarray, prior_weight: np.ndarray,
                      eo_weight: np.ndarray, offset_g: Optional[np.ndarray] = None,
                      offset_weight: Optional[np.ndarray] = None):
    """The prior information on the seven datum parameters, ``H`` (7, 7), in 1/m^2.

    Parameters
    ----------
    eo : numpy.ndarray, shape (n, 6)
        Approximate exterior orientation.
    xyz : numpy.ndarray, shape (m, 3)
        Approximate points.
    prior_weight : numpy.ndarray, shape (m, 3, 3)
        Point prior weights (zero for tie points).
    eo_weight : numpy.ndarray, shape (n, 6)
        Diagonal EO prior weights (zero: free).
    offset_g : numpy.ndarray, shape (m, 3, q), optional
        Design of the databases' offsets per point (:class:`~vectoradjust.adjust.offsets.
        OffsetModel` ``g``): what they absorb fixes nothing.
    offset_weight : numpy.ndarray, shape (q,), optional
        Prior weights of the offsets (0: estimated freely).

    Returns
    -------
    h : numpy.ndarray, shape (7, 7)
    center : numpy.ndarray, shape (3,)
    extent : float
    """
    center, extent = block_frame(eo, xyz)
    xyz = np.where(np.isfinite(xyz), xyz, center)
    gp = point_helmert(xyz, center, extent)
    w = np.nan_to_num(np.asarray(prior_weight, float))
    wg = np.matmul(w, gp)
    h = np.einsum("mia,mib->ab", gp, wg)
    if offset_g is not None and offset_g.shape[2]:
        a = np.einsum("mia,miq->aq", wg, offset_g)
        c = np.einsum("miq,mij,mjr->qr", offset_g, w, offset_g)
        if offset_weight is not None:
            c = c + np.diag(np.asarray(offset_weight, float))
        h = h - a @ np.linalg.pinv(c, hermitian=True) @ a.T
    ge = camera_helmert(eo, center, extent)
    we = np.nan_to_num(np.asarray(eo_weight, float))
    h = h + np.einsum("nia,ni,nib->ab", ge, we, ge)
    return 0.5 * (h + h.T), center, extent


@dataclass
class DatumAnalysis:
    """Which datum parameters the prior information determines, and how well.

    Attributes
    ----------
    information : numpy.ndarray, shape (7, 7)
        :func:`datum_information` (1/m^2; rotations and scale in metres at the extent).
    determined : numpy.ndarray of bool, shape (7,)
        Per :data:`DATUM_PARAMETERS`.
    sigma : numpy.ndarray, shape (7,)
        Standard deviation of each determined parameter (m at the block's extent; inf
        where not determined), from the priors alone.
    free_directions : numpy.ndarray, shape (k, 7)
        Unit vectors of the undetermined combinations.
    center, extent
        The block's centre and extent (m).
    sources : list of str
        What fixes the datum, in words.
    """

    information: np.ndarray
    determined: np.ndarray
    sigma: np.ndarray
    free_directions: np.ndarray
    center: np.ndarray
    extent: float
    sources: list = field(default_factory=list)

    @property
    def complete(self) -> bool:
        """Whether all seven parameters are determined."""
        return bool(self.determined.all()) and not len(self.free_directions)

    @property
    def weak(self) -> list:
        """Determined parameters whose sigma exceeds max(5 m, 2 % of the extent)."""
        limit = max(5.0, 0.02 * self.extent)
        return [p for p, d, s in zip(DATUM_PARAMETERS, self.determined, self.sigma)
                if d and s > limit]

    def to_dict(self) -> dict:
        """For summary.json: per parameter determined or not and its sigma."""
        return {
            "sources": list(self.sources),
            "weak": self.weak,
            "extent_m": float(self.extent),
            "parameters": {
                name: {"determined": bool(d),
                       "sigma_m_at_extent": (float(s) if np.isfinite(s) else None)}
                for name, d, s in zip(DATUM_PARAMETERS, self.determined, self.sigma)},
        }


def analyse_datum(eo: np.ndarray, xyz: np.ndarray, prior_weight: np.ndarray,
                  eo_weight: np.ndarray, offset_g: Optional[np.ndarray] = None,
                  offset_weight: Optional[np.ndarray] = None,
                  sources: Optional[list] = None) -> DatumAnalysis:
    """Datum-defect analysis of a frame-camera block from its prior information.

    Parameters are those of :func:`datum_information`; ``sources`` (words) is kept.

    Returns
    -------
    DatumAnalysis

    Examples
    --------
    Two cameras, one control point: the block can still rotate and change scale.

    >>> import numpy as np
    >>> eo = np.array([[0.0, 0, 1000, 0, 0, 0], [600.0, 0, 1000, 0, 0, 0]])
    >>> xyz = np.array([[300.0, 0, 0], [100.0, 200, 0]])
    >>> w = np.zeros((2, 3, 3)); w[0] = np.eye(3) * 1e4
    >>> a = analyse_datum(eo, xyz, w, np.zeros((2, 6)))
    >>> a.determined.tolist()
    [True, True, True, False, False, False, False]
    """
    h, center, extent = datum_information(eo, xyz, prior_weight, eo_weight, offset_g,
                                          offset_weight)
    lam, vec = np.linalg.eigh(h)
    top = max(float(lam.max(initial=0.0)), 0.0)
    # a direction fixed only to more than the block's extent (an angle of more than a
    # radian, a scale of more than 100 %) is as good as free: it would give absurd sigmas
    limit = min(_SIGMA_UNDETERMINED, extent)
    bad = (lam <= _RELATIVE_DEFECT * top) | (lam <= 1.0 / limit ** 2)
    free = vec[:, bad].T
    determined = _named_determined(free)
    good = ~bad
    cov = (vec[:, good] / lam[good]) @ vec[:, good].T
    sigma = np.where(determined, np.sqrt(np.maximum(np.diag(cov), 0.0)), np.inf)
    return DatumAnalysis(h, determined, sigma, free, center, extent, list(sources or []))


def _named_determined(free: np.ndarray) -> np.ndarray:
    """Which named parameters the free directions ``(k, 7)`` leave determined.

    A shift is free when the free directions contain it alone; a rotation or the scale
    is free when they contain it together with any shift (a rotation about another
    point than the centre is a rotation about the centre plus a shift).
    """
    determined = np.ones(7, bool)
    if not len(free):
        return determined
    determined[:3] = (free[:, :3] ** 2).sum(axis=0) < 0.95
    _, sv, vt = np.linalg.svd(free[:, 3:], full_matrices=False)
    basis = vt[sv > 0.1]
    determined[3:] = (basis ** 2).sum(axis=0) < 0.9
    return determined


_WORDS = {
    "shift": ("the block can move freely in {axes}",
              "measure control points with {axes} coordinates, give camera position priors "
              "(sigma_position in [[images]]: GNSS, EXIF GPS), or declare a road database as "
              "control (role = \"control\" in its [[vectors]] entry)"),
    "height": ("the block can move freely in height",
               "give heights to the control points, a DEM for the shape points (dem = ... in "
               "the [[vectors]] entry) or a layer with Z, or camera height priors "
               "(sigma_position)"),
    "tilt": ("the block can tilt ({axes})",
             "give heights (control points with Z, or a DEM for the road vertices) spread "
             "over the block and not on one line, camera position priors on images not on "
             "one line, or attitude priors (sigma_attitude)"),
    "turn": ("the block can turn about the vertical",
             "give two or more planimetric control points apart, camera position priors on "
             "two or more images apart, a road database as control, or kappa priors "
             "(sigma_attitude)"),
    "scale": ("the block's scale is free",
              "give two or more control points apart, camera position priors on two or more "
              "images apart, or a road database as control"),
}


def _defect_phrases(analysis: DatumAnalysis) -> tuple[list, list]:
    """What can move (phrases) and what would fix it (phrases)."""
    free = ~analysis.determined
    what, mend = [], []
    axes = [a for a, f in zip("XY", free[:2]) if f]
    groups = [("shift", bool(axes), {"axes": " and ".join(axes)}),
              ("height", free[2], {}),
              ("tilt", free[3] or free[4],
               {"axes": " and ".join(f"about the {a} axis" for a, f in zip("XY", free[3:5])
                                     if f)}),
              ("turn", free[5], {}), ("scale", free[6], {})]
    for key, on, fmt in groups:
        if on:
            w, m = _WORDS[key]
            what.append(w.format(**fmt))
            mend.append(m.format(**fmt))
    if not what and len(analysis.free_directions):  # a combination, e.g. about a line
        d = analysis.free_directions[0]
        parts = [DATUM_PARAMETERS[i] for i in np.argsort(-np.abs(d))[:3] if abs(d[i]) > 0.2]
        what.append("the block can move in a combination of " + ", ".join(parts) +
                    " (e.g. rotate about the line through the control points)")
        mend.append("add control, camera position priors or heights away from that line")
    return what, mend


def check_datum(analysis: DatumAnalysis, *, path: Optional[str] = None) -> None:
    """Raise :class:`~vectoradjust.errors.DatumError` unless the datum is complete.

    The message names what can move freely (e.g. "the block can move freely in
    height") and what would fix each (control, camera priors, a DEM, a control road
    database), or, with nothing at all, suggests the free network.
    """
    if analysis.complete:
        return
    what, mend = _defect_phrases(analysis)
    if (~analysis.determined).all():
        raise DatumError(
            "Nothing fixes the block in space: no control point is measured, no image has "
            "a camera position or attitude prior, and no road database is control",
            "Measure three or more control points, give camera positions (sigma_position in "
            "[[images]], e.g. from GNSS or EXIF GPS), or declare a road database as control "
            "(role = \"control\"); or adjust a free network (datum = \"free\" in "
            "[adjustment], --datum free on the command line) for relative precision only",
            path=path, details={"free": list(DATUM_PARAMETERS)})
    free = [p for p, d in zip(DATUM_PARAMETERS, analysis.determined) if not d]
    raise DatumError(
        "The datum is not fixed: " + "; ".join(what) + " (given: " +
        (", ".join(analysis.sources) or "nothing") + ")",
        "To fix it: " + "; ".join(mend) + "; or adjust a free network (datum = \"free\")",
        path=path, details={"free": free or ["combination"]})


def free_network_correction(eo: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, float,
                                                                     np.ndarray]:
    """Inner constraints over the cameras for a reduced camera system ``s`` (6n, 6n).

    Returns ``(g, a, corr)``: ``s + a g g'`` is regular and
    ``(s + a g g')^-1 - corr`` is the pseudo-inverse in the metric that counts an angle
    times the block's extent as metres (``corr = g (G'G)^-2 g' / a``, ``G = T g``,
    ``T = diag(1, 1, 1, L, L, L)``); ``g`` is ``T^2`` times the cameras' similarity
    columns, ``(6n, 7)``.
    """
    eo = np.asarray(eo, float).reshape(-1, 6)
    center, extent = block_frame(eo, np.zeros((0, 3)))
    ge = camera_helmert(eo, center, extent).reshape(-1, 7)
    t = np.tile([1.0, 1.0, 1.0, extent, extent, extent], len(eo))
    gy = t[:, None] * ge
    gtg = gy.T @ gy
    g2 = t[:, None] * gy
    a = float(np.trace(s)) / max(float((g2 * g2).sum()), 1e-300)
    inv2 = np.linalg.inv(gtg @ gtg)
    corr = ge @ inv2 @ ge.T / a
    return g2, a, corr

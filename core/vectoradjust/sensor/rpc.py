"""Rational polynomial coefficient (RPC00B) sensor model of satellite images.

An RPC maps a ground point (longitude, latitude in degrees on WGS84, height in metres
above the WGS84 *ellipsoid*) to an image position by ratios of cubic polynomials in the
normalised ground coordinates::

    L = (lon - LONG_OFF) / LONG_SCALE,  P = (lat - LAT_OFF) / LAT_SCALE,
    H = (h - HEIGHT_OFF) / HEIGHT_SCALE
    col_n = samp_num(L, P, H) / samp_den(L, P, H),  row_n = line_num(.) / line_den(.)
    col = col_n * SAMP_SCALE + SAMP_OFF,             row = row_n * LINE_SCALE + LINE_OFF

Each polynomial has 20 coefficients in the RPC00B term order (as GDAL uses it)::

    1, L, P, H, LP, LH, PH, L^2, P^2, H^2, PLH, L^3, LP^2, LH^2, L^2P, P^3, PH^2,
    L^2H, P^2H, H^3

Pixel convention (``origin``): the raw formula above puts the *centre* of the first pixel
at (0, 0) (``origin="center"``). GDAL's RPC transformer (and so rasterio's
``rasterio.transform.RPCTransformer``) puts the upper-left *corner* of the first pixel at
(0, 0), its centre at (0.5, 0.5), and returns the raw value **plus** half a pixel in both
column and row: ``corner = center + 0.5``. That is ``origin="corner"``, the default here;
``tests/test_rpc.py`` pins the direction against rasterio (GDAL 3.10) on real RPCs.

:meth:`RpcModel.project_partials` gives the analytic partials of column and row with
respect to longitude, latitude (degrees) and height (metres); :meth:`RpcModel.localize`
inverts the model for a given height by Newton's method, vectorised over points.

Image-space bias (Grodecki & Dial 2003): six parameters ``p = (a0, a1, a2, b0, b1, b2)``
in pixels, with ``u = (col_c - SAMP_OFF) / SAMP_SCALE`` and ``v = (row_c - LINE_OFF) /
LINE_SCALE`` of the raw (centre-convention) position before the bias::

    col' = col + a0 + a1 u + a2 v,   row' = row + b0 + b1 u + b2 v

:data:`BIAS_MODELS` names the parameter subsets in use; :func:`biased_partials` gives the
observation model with its partials, :func:`fold_bias` a corrected RPC without the bias.

Imports numpy only.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from vectoradjust.errors import InputFileError

__all__ = ["RpcModel", "BIAS_MODELS", "biased_partials", "fold_bias"]

#: Bias parameter subsets: indices into ``p = (a0, a1, a2, b0, b1, b2)``.
BIAS_MODELS = {
    "none": (),
    "shift": (0, 3),
    "shift+drift": (0, 2, 3, 5),
    "affine": (0, 1, 2, 3, 4, 5),
}

#: Exponents of (L, P, H) of the 20 RPC00B terms, in order.
_EXPONENTS = (
    (0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, 0, 1), (0, 1, 1),
    (2, 0, 0), (0, 2, 0), (0, 0, 2), (1, 1, 1), (3, 0, 0), (1, 2, 0), (1, 0, 2),
    (2, 1, 0), (0, 3, 0), (0, 1, 2), (2, 0, 1), (0, 2, 1), (0, 0, 3),
)
_SCALARS = ("line_off", "samp_off", "lat_off", "long_off", "height_off",
            "line_scale", "samp_scale", "lat_scale", "long_scale", "height_scale")
_POLYS = ("line_num", "line_den", "samp_num", "samp_den")
_OPTIONAL = ("err_bias", "err_rand")
#: field name -> GDAL metadata key
_GDAL_KEYS = {**{f: f.upper() for f in _SCALARS}, **{p: p.upper() + "_COEFF" for p in _POLYS}}
_ORIGINS = {"corner": 0.5, "center": 0.0}
#: points per block in the vectorised evaluation (keeps the (20, m) temporaries in cache)
_CHUNK = 1 << 14
#: Newton of :meth:`RpcModel.localize`: iterations, pixel tolerance, divergence bound
_NEWTON_MAX_ITER = 30
_NEWTON_TOL_PX = 1e-8
_NEWTON_DIVERGED = 10.0


def _derivative_matrices() -> np.ndarray:
    """``D[a] @ c``: the RPC00B coefficients of the derivative along axis ``a`` (L, P, H)."""
    index = {e: k for k, e in enumerate(_EXPONENTS)}
    d = np.zeros((3, 20, 20))
    for k, e in enumerate(_EXPONENTS):
        for axis in range(3):
            if e[axis]:
                lower = tuple(x - (i == axis) for i, x in enumerate(e))
                d[axis, index[lower], k] = e[axis]
    return d


_DERIVATIVES = _derivative_matrices()


def _monomials(L: np.ndarray, P: np.ndarray, H: np.ndarray) -> np.ndarray:
    """The 20 RPC00B terms of ``m`` points, shape ``(20, m)``."""
    t = np.empty((20, L.shape[0]))
    t[0] = 1.0
    t[1], t[2], t[3] = L, P, H
    np.multiply(L, P, out=t[4])
    np.multiply(L, H, out=t[5])
    np.multiply(P, H, out=t[6])
    np.multiply(L, L, out=t[7])
    np.multiply(P, P, out=t[8])
    np.multiply(H, H, out=t[9])
    np.multiply(t[4], H, out=t[10])   # PLH
    np.multiply(t[7], L, out=t[11])   # L^3
    np.multiply(t[8], L, out=t[12])   # LP^2
    np.multiply(t[9], L, out=t[13])   # LH^2
    np.multiply(t[7], P, out=t[14])   # L^2P
    np.multiply(t[8], P, out=t[15])   # P^3
    np.multiply(t[9], P, out=t[16])   # PH^2
    np.multiply(t[7], H, out=t[17])   # L^2H
    np.multiply(t[8], H, out=t[18])   # P^2H
    np.multiply(t[9], H, out=t[19])   # H^3
    return t


def _evaluate(k: np.ndarray, L: np.ndarray, P: np.ndarray, H: np.ndarray):
    """Normalised column and row (and their derivatives along L, P, H when ``k`` has them).

    ``k`` is :meth:`RpcModel._coefficients`: ``(4, 20)`` gives ``(cn, rn, None, None)``,
    ``(16, 20)`` gives ``(cn, rn, dcn, drn)`` with ``dcn``, ``drn`` of shape ``(3, m)``.
    """
    v = k @ _monomials(L, P, H)
    if k.shape[0] == 4:
        return v[0] / v[1], v[2] / v[3], None, None
    cn = v[0] / v[4]
    rn = v[8] / v[12]
    dcn = (v[1:4] - cn * v[5:8]) / v[4]
    drn = (v[9:12] - rn * v[13:16]) / v[12]
    return cn, rn, dcn, drn


def _origin_shift(origin: str) -> float:
    try:
        return _ORIGINS[origin]
    except KeyError:
        raise ValueError(f"origin must be 'corner' or 'center', not {origin!r}") from None


def _flat(*arrays) -> list[np.ndarray]:
    """Broadcast the arguments to one shape and flatten them to float64 vectors."""
    b = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in arrays))
    return [np.ravel(a) for a in b]


@dataclass(eq=False)
class RpcModel:
    """An RPC00B sensor model (see the module docstring for the formula and conventions).

    Attributes
    ----------
    line_off, samp_off, lat_off, long_off, height_off : float
        Offsets of row and column (px), latitude and longitude (degrees), height (m).
    line_scale, samp_scale, lat_scale, long_scale, height_scale : float
        Scales of the same (non-zero).
    line_num, line_den, samp_num, samp_den : numpy.ndarray
        The ``(20,)`` coefficients of each polynomial in RPC00B term order.
    err_bias, err_rand : float or None
        The vendor's RMS bias and random error (m per horizontal axis; -1 when unknown,
        as GDAL writes it); ``None`` when not given.
    source : str
        Where the model came from (a file name), for messages.

    Notes
    -----
    Two models are equal (``==``) when all their numbers are; ``source`` is not compared.
    The arrays are converted to float64 and every value is checked on construction
    (:class:`~vectoradjust.errors.InputFileError` naming ``source`` and the GDAL key).

    Examples
    --------
    A toy model whose column follows longitude and row the negative latitude:

    >>> import numpy as np
    >>> zero = np.zeros(20)
    >>> den = zero.copy(); den[0] = 1.0
    >>> samp = zero.copy(); samp[1] = 1.0
    >>> line = zero.copy(); line[2] = -1.0
    >>> rpc = RpcModel(line_off=500.0, samp_off=500.0, lat_off=45.0, long_off=7.0,
    ...                height_off=0.0, line_scale=500.0, samp_scale=500.0, lat_scale=0.01,
    ...                long_scale=0.01, height_scale=100.0, line_num=line, line_den=den,
    ...                samp_num=samp, samp_den=den)
    >>> rpc.project(7.005, 45.0, 0.0, origin="center")
    array([[750., 500.]])
    >>> rpc.project(7.005, 45.0, 0.0)
    array([[750.5, 500.5]])
    >>> rpc.localize(750.5, 500.5, 0.0).round(9)
    array([[ 7.005, 45.   ]])
    >>> rpc.outside_domain([7.005, 7.02], 45.0, 0.0)
    array([False,  True])
    """

    line_off: float
    samp_off: float
    lat_off: float
    long_off: float
    height_off: float
    line_scale: float
    samp_scale: float
    lat_scale: float
    long_scale: float
    height_scale: float
    line_num: np.ndarray
    line_den: np.ndarray
    samp_num: np.ndarray
    samp_den: np.ndarray
    err_bias: Optional[float] = None
    err_rand: Optional[float] = None
    source: str = "<rpc>"

    def __post_init__(self) -> None:
        for name in _SCALARS:
            value = _number(getattr(self, name), _GDAL_KEYS[name], self.source)
            if name.endswith("_scale") and value == 0.0:
                raise _error(self.source, f"{_GDAL_KEYS[name]} is zero",
                             "Every RPC scale must be non-zero (check the RPC metadata)",
                             _GDAL_KEYS[name])
            setattr(self, name, value)
        for name in _POLYS:
            setattr(self, name, _coefficient_vector(getattr(self, name), _GDAL_KEYS[name],
                                                    self.source))
        for name in ("line_den", "samp_den"):
            if not np.any(getattr(self, name)):
                raise _error(self.source, f"{_GDAL_KEYS[name]} is all zero",
                             "A denominator needs a non-zero coefficient (usually the first, 1.0)",
                             _GDAL_KEYS[name])
        for name in _OPTIONAL:
            if getattr(self, name) is not None:
                setattr(self, name, _number(getattr(self, name), name.upper(), self.source))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, RpcModel):
            return NotImplemented
        return (all(getattr(self, f) == getattr(other, f) for f in _SCALARS + _OPTIONAL)
                and all(np.array_equal(getattr(self, p), getattr(other, p)) for p in _POLYS))

    __hash__ = None  # type: ignore[assignment]

    # ------------------------------------------------------------------ GDAL metadata
    @classmethod
    def from_gdal(cls, d: Mapping, source: str = "<rpc>") -> RpcModel:
        """Build the model from GDAL's RPC metadata dictionary.

        Parameters
        ----------
        d : Mapping
            Keys ``LINE_OFF``, ``SAMP_OFF``, ``LAT_OFF``, ``LONG_OFF``, ``HEIGHT_OFF``, the
            five ``..._SCALE`` and ``LINE_NUM_COEFF``, ``LINE_DEN_COEFF``,
            ``SAMP_NUM_COEFF``, ``SAMP_DEN_COEFF`` (case-insensitive), optionally
            ``ERR_BIAS`` and ``ERR_RAND``. Values as GDAL gives them (strings, the
            coefficients as 20 numbers separated by blanks) or as numbers and lists, as in
            rasterio's ``src.rpcs.to_gdal()``.
        source : str
            The file the metadata came from, named in error messages.

        Returns
        -------
        RpcModel

        Raises
        ------
        vectoradjust.errors.InputFileError
            A key is missing, a value is not a finite number, a coefficient list does not
            have 20 numbers, a scale is zero or a denominator all zero.
        """
        if not isinstance(d, Mapping):
            raise _error(source, f"the RPC metadata is a {type(d).__name__}, not a mapping",
                         "Pass the RPC metadata dictionary (rasterio: src.rpcs.to_gdal())")
        upper = {str(k).strip().upper(): v for k, v in d.items()}
        missing = [key for key in _GDAL_KEYS.values() if key not in upper]
        if missing:
            raise _error(source, f"the RPC metadata lacks {', '.join(missing)}",
                         "Give the ten offsets and scales and the four lists of 20 "
                         "coefficients (RPC00B) as GDAL's RPC metadata domain has them",
                         missing[0])
        kw: dict[str, Any] = {f: upper[k] for f, k in _GDAL_KEYS.items()}
        for name in _OPTIONAL:
            value = upper.get(name.upper())
            if value is not None and not (isinstance(value, str) and not value.strip()):
                kw[name] = value
        return cls(**kw, source=source)

    def to_gdal(self) -> dict:
        """The GDAL RPC metadata dictionary (values as strings, as GDAL writes them).

        ``RpcModel.from_gdal(m.to_gdal()) == m``; ``ERR_BIAS`` / ``ERR_RAND`` appear only
        when set. Numbers are written by ``repr`` (shortest exact round trip).
        """
        out = {_GDAL_KEYS[f]: repr(float(getattr(self, f))) for f in _SCALARS}
        for p in _POLYS:
            out[_GDAL_KEYS[p]] = " ".join(repr(float(c)) for c in getattr(self, p))
        for name in _OPTIONAL:
            if getattr(self, name) is not None:
                out[name.upper()] = repr(float(getattr(self, name)))
        return out

    # ------------------------------------------------------------------ the model
    def _coefficients(self, derivatives: bool) -> np.ndarray:
        """Rows samp_num, samp_den, line_num, line_den; with ``derivatives`` each followed
        by the coefficients of its derivatives along L, P, H: ``(16, 20)``, else ``(4, 20)``."""
        polys = (self.samp_num, self.samp_den, self.line_num, self.line_den)
        if not derivatives:
            return np.stack(polys)
        return np.stack([row for c in polys for row in (c, *(_DERIVATIVES @ c))])

    def normalized(self, lon, lat, h) -> np.ndarray:
        """Normalised ground coordinates ``L, P, H`` (for domain checks).

        Parameters
        ----------
        lon, lat : array_like
            Degrees (WGS84), broadcastable with ``h``.
        h : array_like
            Ellipsoidal height (m).

        Returns
        -------
        numpy.ndarray
            Shape ``(n, 3)``.
        """
        lon, lat, h = _flat(lon, lat, h)
        out = np.empty((lon.size, 3))
        out[:, 0] = (lon - self.long_off) / self.long_scale
        out[:, 1] = (lat - self.lat_off) / self.lat_scale
        out[:, 2] = (h - self.height_off) / self.height_scale
        return out

    def outside_domain(self, lon, lat, h, margin: float = 0.1) -> np.ndarray:
        """Whether points lie outside the RPC's fitted domain.

        Parameters
        ----------
        lon, lat, h : array_like
            Ground points as for :meth:`normalized`.
        margin : float
            Allowed excess: a point is outside when any ``|L|, |P|, |H| > 1 + margin``.

        Returns
        -------
        numpy.ndarray
            Boolean ``(n,)``; points with a non-finite coordinate count as outside.
        """
        n = self.normalized(lon, lat, h)
        with np.errstate(invalid="ignore"):
            return ~np.all(np.abs(n) <= 1.0 + margin, axis=1)

    def project(self, lon, lat, h, origin: str = "corner") -> np.ndarray:
        """Image positions of ground points.

        Parameters
        ----------
        lon, lat : array_like
            Degrees (WGS84), broadcastable with ``h``.
        h : array_like
            Ellipsoidal height (m).
        origin : {"corner", "center"}
            Pixel convention (module docstring): ``"corner"`` is GDAL's.

        Returns
        -------
        numpy.ndarray
            ``(n, 2)``: column, row in pixels.
        """
        shift = _origin_shift(origin)
        nrm = self.normalized(lon, lat, h)
        k = self._coefficients(False)
        out = np.empty((nrm.shape[0], 2))
        for s in range(0, nrm.shape[0], _CHUNK):
            b = slice(s, s + _CHUNK)
            cn, rn, _, _ = _evaluate(k, nrm[b, 0], nrm[b, 1], nrm[b, 2])
            out[b, 0] = cn * self.samp_scale + (self.samp_off + shift)
            out[b, 1] = rn * self.line_scale + (self.line_off + shift)
        return out

    def project_partials(self, lon, lat, h, origin: str = "corner"
                         ) -> tuple[np.ndarray, np.ndarray]:
        """Image positions and their analytic partials with respect to the ground point.

        Parameters
        ----------
        lon, lat, h, origin
            As for :meth:`project`.

        Returns
        -------
        xy : numpy.ndarray
            ``(n, 2)``: column, row in pixels.
        jac : numpy.ndarray
            ``(n, 2, 3)``: ``d(col, row) / d(lon [deg], lat [deg], h [m])`` in px per unit.
        """
        shift = _origin_shift(origin)
        lon, lat, h = _flat(lon, lat, h)
        n = lon.size
        k = self._coefficients(True)
        ground_scale = np.array([self.long_scale, self.lat_scale, self.height_scale])
        fc = (self.samp_scale / ground_scale)[:, None]
        fr = (self.line_scale / ground_scale)[:, None]
        xy = np.empty((n, 2))
        jac = np.empty((n, 2, 3))
        for s in range(0, n, _CHUNK):
            b = slice(s, s + _CHUNK)
            L = (lon[b] - self.long_off) / self.long_scale
            P = (lat[b] - self.lat_off) / self.lat_scale
            H = (h[b] - self.height_off) / self.height_scale
            cn, rn, dcn, drn = _evaluate(k, L, P, H)
            xy[b, 0] = cn * self.samp_scale + (self.samp_off + shift)
            xy[b, 1] = rn * self.line_scale + (self.line_off + shift)
            jac[b, 0, :] = (dcn * fc).T
            jac[b, 1, :] = (drn * fr).T
        return xy, jac

    def localize(self, col, row, h, origin: str = "corner") -> np.ndarray:
        """Ground longitude and latitude of image positions at given heights (the inverse).

        Newton's method in normalised coordinates from the RPC's centre, vectorised over
        the points still iterating; at most 30 iterations, converged when the point
        reprojects within 1e-8 px in column and row. Points that do not converge (or
        leave ten times the RPC's domain, or have a non-finite input) come back NaN.

        Parameters
        ----------
        col, row : array_like
            Pixel position in the ``origin`` convention, broadcastable with ``h``.
        h : array_like
            Ellipsoidal height (m).
        origin : {"corner", "center"}
            Pixel convention (module docstring).

        Returns
        -------
        numpy.ndarray
            ``(n, 2)``: longitude, latitude in degrees.
        """
        shift = _origin_shift(origin)
        col, row, h = _flat(col, row, h)
        tc = (col - shift - self.samp_off) / self.samp_scale
        tr = (row - shift - self.line_off) / self.line_scale
        hn = (h - self.height_off) / self.height_scale
        k = self._coefficients(True)
        tol = (_NEWTON_TOL_PX / abs(self.samp_scale), _NEWTON_TOL_PX / abs(self.line_scale))
        out = np.full((tc.size, 2), np.nan)
        for s in range(0, tc.size, _CHUNK):
            b = slice(s, s + _CHUNK)
            lp, done = _newton(k, tc[b], tr[b], hn[b], tol)
            out[b, 0][done] = lp[0, done] * self.long_scale + self.long_off
            out[b, 1][done] = lp[1, done] * self.lat_scale + self.lat_off
        return out


def _newton(k: np.ndarray, tc: np.ndarray, tr: np.ndarray, hn: np.ndarray,
            tol: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Normalised ``L, P`` (2, m) with ``col_n = tc``, ``row_n = tr`` at ``H = hn``, and
    whether each converged (within ``tol`` in normalised column and row)."""
    m = tc.size
    lp = np.zeros((2, m))
    done = np.zeros(m, dtype=bool)
    active = np.flatnonzero(np.isfinite(tc) & np.isfinite(tr) & np.isfinite(hn))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for _ in range(_NEWTON_MAX_ITER):
            if active.size == 0:
                break
            cur = lp[:, active]
            cn, rn, dcn, drn = _evaluate(k, cur[0], cur[1], hn[active])
            ec, er = cn - tc[active], rn - tr[active]
            ok = (np.abs(ec) <= tol[0]) & (np.abs(er) <= tol[1])
            done[active[ok]] = True
            det = dcn[0] * drn[1] - dcn[1] * drn[0]
            new = cur - np.stack([drn[1] * ec - dcn[1] * er, dcn[0] * er - drn[0] * ec]) / det
            keep = ~ok & np.all(np.abs(new) < _NEWTON_DIVERGED, axis=0)
            active = active[keep]
            lp[:, active] = new[:, keep]
    return lp, done


# ---------------------------------------------------------------------- bias
def _bias_params(params) -> np.ndarray:
    p = np.asarray(params, dtype=np.float64)
    if p.shape != (6,):
        raise ValueError(f"bias parameters must have shape (6,), not {p.shape}")
    return p


def biased_partials(rpc: RpcModel, lon, lat, h, params, origin: str = "corner"
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The observation model with image-space bias, and its analytic partials.

    Parameters
    ----------
    rpc : RpcModel
    lon, lat, h : array_like
        Ground points (degrees, ellipsoidal metres), broadcastable.
    params : array_like
        ``(6,)``: ``a0, a1, a2, b0, b1, b2`` in pixels (module docstring).
    origin : {"corner", "center"}
        Pixel convention of the result.

    Returns
    -------
    xy : numpy.ndarray
        ``(n, 2)``: biased column ``col'`` and row ``row'``.
    d_ground : numpy.ndarray
        ``(n, 2, 3)``: ``d(col', row') / d(lon, lat, h)``, including the bias's own
        dependence on ``u``, ``v``.
    d_params : numpy.ndarray
        ``(n, 2, 6)``: ``d(col', row') / d(a0, a1, a2, b0, b1, b2)``.
    """
    a0, a1, a2, b0, b1, b2 = _bias_params(params)
    shift = _origin_shift(origin)
    xy, jac = rpc.project_partials(lon, lat, h, origin="center")
    u = (xy[:, 0] - rpc.samp_off) / rpc.samp_scale
    v = (xy[:, 1] - rpc.line_off) / rpc.line_scale
    out = np.empty_like(xy)
    out[:, 0] = xy[:, 0] + (a0 + shift) + a1 * u + a2 * v
    out[:, 1] = xy[:, 1] + (b0 + shift) + b1 * u + b2 * v
    du = jac[:, 0, :] / rpc.samp_scale
    dv = jac[:, 1, :] / rpc.line_scale
    d_ground = np.empty_like(jac)
    d_ground[:, 0, :] = jac[:, 0, :] + a1 * du + a2 * dv
    d_ground[:, 1, :] = jac[:, 1, :] + b1 * du + b2 * dv
    d_params = np.zeros((xy.shape[0], 2, 6))
    d_params[:, 0, 0] = 1.0
    d_params[:, 0, 1] = u
    d_params[:, 0, 2] = v
    d_params[:, 1, 3] = 1.0
    d_params[:, 1, 4] = u
    d_params[:, 1, 5] = v
    return out, d_ground, d_params


def _cube(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.linspace(-1.0, 1.0, n)
    g = np.meshgrid(t, t, t, indexing="ij")
    return g[0].ravel(), g[1].ravel(), g[2].ravel()


def _biased_normalised(rpc: RpcModel, p: np.ndarray, t: np.ndarray):
    """Normalised column and row with the bias added, and both denominators, at terms ``t``."""
    sd, ld = rpc.samp_den @ t, rpc.line_den @ t
    cn, rn = (rpc.samp_num @ t) / sd, (rpc.line_num @ t) / ld
    bc = (p[0] + p[1] * cn + p[2] * rn) / rpc.samp_scale
    br = (p[3] + p[4] * cn + p[5] * rn) / rpc.line_scale
    return cn + bc, rn + br, sd, ld


def fold_bias(rpc: RpcModel, params, grid: int = 11) -> tuple[RpcModel, float]:
    """A corrected RPC whose :meth:`~RpcModel.project` equals the biased observation model.

    A pure shift (only ``a0``, ``b0`` non-zero) is exact: only ``SAMP_OFF`` and
    ``LINE_OFF`` change. Otherwise the two numerators are refitted (the denominators kept)
    by linear least squares, weighted so that the normalised image misfit is minimised, on
    a ``grid x grid x grid`` cube over the normalised domain ``[-1, 1]^3``. ``a0``, ``a1``
    (``b0``, ``b2``) are represented exactly; the cross terms ``a2 v`` and ``b1 u`` only
    approximately, because ``v`` has the other denominator.

    Parameters
    ----------
    rpc : RpcModel
    params : array_like
        ``(6,)``: ``a0, a1, a2, b0, b1, b2`` in pixels.
    grid : int
        Nodes per axis of the fitting cube (at least 4: the cubic terms).

    Returns
    -------
    folded : RpcModel
        The corrected model (same ``source``, ``err_bias``, ``err_rand``).
    misfit : float
        The largest distance (px) between ``folded.project`` and the biased model on a
        check cube of ``2 * grid + 1`` nodes per axis (0.0 for a pure shift).
    """
    p = _bias_params(params)
    if grid < 4:
        raise ValueError(f"grid must be at least 4 (cubic terms), not {grid}")
    copies = {name: getattr(rpc, name).copy() for name in _POLYS}
    if not np.any(p[[1, 2, 4, 5]]):
        return dataclasses.replace(rpc, samp_off=rpc.samp_off + p[0],
                                   line_off=rpc.line_off + p[3], **copies), 0.0
    t = _monomials(*_cube(grid))
    cb, rb, sd, ld = _biased_normalised(rpc, p, t)
    copies["samp_num"] = np.linalg.lstsq((t / sd).T, cb, rcond=None)[0]
    copies["line_num"] = np.linalg.lstsq((t / ld).T, rb, rcond=None)[0]
    folded = dataclasses.replace(rpc, **copies)
    t = _monomials(*_cube(2 * grid + 1))
    cb, rb, _, _ = _biased_normalised(rpc, p, t)
    cf, rf, _, _ = _evaluate(folded._coefficients(False), t[1], t[2], t[3])
    misfit = np.hypot((cf - cb) * rpc.samp_scale, (rf - rb) * rpc.line_scale)
    return folded, float(misfit.max())


# ---------------------------------------------------------------------- parsing
def _error(source: str, what: str, mend: str, key: Optional[str] = None) -> InputFileError:
    path = None if source.startswith("<") else source
    return InputFileError(f"{source}: {what}", mend, path=path,
                          details={"key": key} if key else None)


def _number(value: Any, key: str, source: str) -> float:
    """A finite float from a number or a numeric string."""
    try:
        x = float(value.strip() if isinstance(value, str) else value)
    except (TypeError, ValueError):
        raise _error(source, f"RPC {key} is not a number ({value!r})",
                     "Give a number, e.g. '1.0'", key) from None
    if not math.isfinite(x):
        raise _error(source, f"RPC {key} is not finite ({value!r})", "Give a finite number", key)
    return x


def _coefficient_vector(value: Any, key: str, source: str) -> np.ndarray:
    """20 finite coefficients from a blank-separated string or a sequence of numbers."""
    items = value.replace(",", " ").split() if isinstance(value, str) else value
    try:
        c = np.asarray(items, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise _error(source, f"RPC {key} is not a list of numbers ({value!r})",
                     "Give 20 numbers separated by blanks", key) from None
    if c.size != 20:
        raise _error(source, f"RPC {key} has {c.size} coefficients, not 20",
                     "RPC00B needs 20 coefficients per polynomial (check that the list is "
                     "complete)", key)
    if not np.all(np.isfinite(c)):
        raise _error(source, f"RPC {key} has a non-finite coefficient", "Give finite numbers",
                     key)
    return c

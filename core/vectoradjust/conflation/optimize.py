"""The bounded minimisers of the covariance fit (:func:`fit_covariance`): projected
quasi-Newton (:func:`_projected_bfgs`) and the polish on a fixed lattice
(:func:`_lattice_min`).

Heart module: numpy and scipy only.
"""

from __future__ import annotations

import numpy as np

__all__ = []


def _projected_bfgs(fg, x0, lo, hi, max_iter: int = 60, xtol: float = 1e-3,
                    ftol: float = 1e-4, max_step: float = 1.0, max_cap: float = 8.0):
    """Minimise ``f`` in the box ``[lo, hi]`` from ``x0``: BFGS on the free variables
    (``fg(x) = (f, gradient)`` or ``(f, gradient, H)``), steps projected onto the box,
    backtracking (Armijo).

    With ``H``, an approximation of the Hessian (for :func:`_fit_loo` the expected
    one, :func:`_loo_score_fisher`), the inverse Hessian starts from ``H^-1`` and
    restarts from it, instead of a multiple of the identity: the first steps already
    follow the ridge of sill and length, and the secant updates correct what ``H``
    misses. A step moves no coordinate by more than ``max_step``; after a capped step
    taken in full the cap doubles, up to ``max_cap`` times ``max_step`` (a vanishing
    sill reaches its bound in a few steps). Stops when a step moves every coordinate by
    less than ``xtol`` or ``f`` no longer decreases. A variable at a bound whose
    gradient pushes outwards stays there.
    """
    x = np.clip(np.asarray(x0, float), lo, hi)
    fx, g, *hx = fg(x)
    if not np.isfinite(fx):
        return x
    h, first, gamma, was = np.eye(len(x)), True, 1.0, np.zeros(len(x), bool)
    cap = max_step
    if hx:
        h, first = _inverse_on(hx[0], was), False
    for _ in range(max_iter):
        fixed = ((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0))
        if np.any(fixed != was):  # another active set: forget the curvature across it
            h, was = (_inverse_on(hx[0], fixed) if hx else np.eye(len(x)) * gamma), fixed
        hf = np.where(fixed[:, None] | fixed[None, :], 0.0, h)
        d = -hf @ np.where(fixed, 0.0, g)
        if not g @ d < 0:  # not a descent direction: restart
            h = _inverse_on(hx[0], fixed) if hx else np.eye(len(x)) * gamma
            d = -np.where(fixed[:, None] | fixed[None, :], 0.0, h) @ np.where(fixed, 0.0, g)
            if not g @ d < 0:
                h, d = np.eye(len(x)) * gamma, -gamma * np.where(fixed, 0.0, g)
        big = max(float(np.max(np.abs(d))), 1e-300)
        t, moved, full = min(1.0, cap / big), False, True
        for _ in range(30):
            xn = np.clip(x + t * d, lo, hi)
            fn, gn, *hn = fg(xn)
            if np.isfinite(fn) and fn <= fx + 1e-4 * (g @ (xn - x)):
                moved = True
                break
            t, full = t * 0.3, False
        if not moved:
            break
        # a capped step taken in full: the next may be longer (a vanishing sill reaches
        # its bound in a few steps); a shortened one: back to max_step
        cap = min(2.0 * cap, max_cap * max_step) if full and big > cap else max_step
        sv, yv = xn - x, gn - g
        x, done = xn, (np.max(np.abs(sv)) < xtol or fx - fn < ftol)
        fx, g, hx = fn, gn, hn
        if done:
            break
        sy = float(sv @ yv)
        if sy > 1e-12:
            if first:  # the first step sets the scale of the inverse Hessian
                gamma, first = sy / float(yv @ yv), False
                h = np.eye(len(x)) * gamma
            rho = 1.0 / sy
            v = np.eye(len(x)) - rho * np.outer(sv, yv)
            h = v @ h @ v.T + rho * np.outer(sv, sv)
    return x


def _inverse_on(hess: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """The inverse of ``hess`` on the free variables (0 on the fixed ones), with a
    ridge of 1e-9 of its largest diagonal (a parameter without influence, e.g. the
    length of a vanishing sill, gets a large but finite step, which the caller caps)."""
    free = ~fixed
    out = np.zeros_like(hess)
    if not free.any():
        return out
    hf = hess[np.ix_(free, free)]
    ridge = 1e-9 * max(float(np.max(np.abs(np.diag(hf)))), 1e-300)
    try:
        out[np.ix_(free, free)] = np.linalg.inv(hf + ridge * np.eye(len(hf)))
    except np.linalg.LinAlgError:
        out[np.ix_(free, free)] = np.eye(len(hf)) / max(float(np.max(np.diag(hf))), 1e-300)
    return out


def _lattice_min(f, x, lo, hi, step: float = 0.05, max_moves: int = 200, fg=None):
    """Polish a minimum on the fixed lattice ``step * Z^3`` (logarithms: 5 %).

    The optimiser's path depends on the last bits of its sums, which differ between
    numpy builds (QGIS's and the command line's); ending on the lattice (the best of
    the rounded optimum and its 6 neighbours along the axes, repeated up to
    ``max_moves`` times while a neighbour is really better) gives both the same
    parameters. :func:`_fit_loo` makes one such move: its quasi-Newton optimum is
    converged, and further moves only creep along the flat ridge of sill and length
    (differences of the score far below its own uncertainty). With ``fg(x) = (f,
    gradient)`` only the neighbours downhill of the rounded point are scored (one per
    axis: a convex ``f`` rises the other way, ``f(x + s) >= f(x) + g' s``), three
    scores instead of six.
    """
    lo_i, hi_i = np.ceil(lo / step - 1e-9), np.floor(hi / step + 1e-9)
    cur = np.clip(np.round(np.asarray(x) / step), lo_i, hi_i)
    seen: dict = {}

    def val(i):
        key = tuple(int(v) for v in i)
        if key not in seen:
            seen[key] = f(np.asarray(i, float) * step)
        return seen[key]

    moves = np.vstack([np.eye(3), -np.eye(3)])
    for _ in range(max_moves):
        if fg is None:
            best, ahead = val(cur), moves
        else:  # the score and its slope at once: only the downhill moves
            best, g = fg(cur * step)
            seen.setdefault(tuple(int(v) for v in cur), best)
            ahead = moves[(moves @ g) < 0]
        cand = [np.clip(cur + m, lo_i, hi_i) for m in ahead]
        if not cand:
            break
        vals = [val(c) for c in cand]
        j = int(np.argmin(vals))
        if not vals[j] < best - 1e-9 * max(abs(best), 1.0):
            break
        cur, best = cand[j], vals[j]
    return cur * step, float(best)

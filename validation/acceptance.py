"""Acceptance criteria of the validation scripts: bands, PASS/FAIL lines, exit status.

Every script in ``validation/`` states its criteria in its docstring, measures them,
prints one line per criterion::

    PASS  CE90 covers the adjusted shape points         0.8897 in [0.8420, 0.9548]
    FAIL  LE90 covers the adjusted shape points         0.7702 not in [0.8485, 0.9498]

and exits with status 1 when one fails (2: its input data are missing). The same
script with a smaller sample (``--fast``: one seed or a few runs) is the fast tier of
``tests/test_validation.py``; its bands are computed from the sample it has, so that a
correct implementation passes with >= 99 % probability and a wrong one (e.g. every sigma
20 % too small) still fails.

How the bands are made
----------------------
A share ``p`` (a coverage, a detection rate) measured on ``n`` samples whose true value
lies in ``[p_lo, p_hi]`` passes when it lies between the ``alpha / 2`` quantile of
``Binomial(n_eff, p_lo)`` and the ``1 - alpha / 2`` quantile of ``Binomial(n_eff, p_hi)``
(over ``n_eff``), with ``n_eff = n / deff``: samples of one run share that run's
orientation or field errors, the design effect ``deff`` (variance between runs over the
binomial variance, measured by the full tier) says by how much the sample is smaller
than its count. A mean ``m`` with standard error ``se`` whose true value lies in
``[lo, hi]`` passes within ``[lo - z se, hi + z se]``. ``alpha`` of one script is 0.01
divided by the number of its statistical criteria (Bonferroni): all of them pass together
with >= 99 % probability. Deterministic criteria (invariants, a real data set that does
not change) have fixed bounds.

:func:`coverage_1d` and :func:`coverage_2d` give the coverage of a 90 % interval / circle
whose sigma is ``k`` times the true one: ``2 Phi(1.645 k) - 1`` and ``1 - 0.1^(k^2)``;
with ``k = 0.8`` they are 0.812 and 0.771, with ``k = 1.2`` 0.952 and 0.964.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.stats import binom, norm

__all__ = ["Criterion", "Criteria", "coverage_1d", "coverage_2d", "design_effect", "share_band",
           "mean_band", "z_two_sided"]

Z90 = 1.6448536269514722


def coverage_1d(k: float) -> float:
    """Coverage of a 1-D 90 % interval built with ``k`` times the true sigma."""
    return float(2.0 * norm.cdf(Z90 * k) - 1.0)


def coverage_2d(k: float) -> float:
    """Coverage of a circular 90 % radius built with ``k`` times the true sigma."""
    return float(1.0 - 0.1 ** (k * k))


def z_two_sided(alpha: float) -> float:
    """The normal quantile of a two-sided test at level ``alpha``."""
    return float(norm.isf(alpha / 2.0))


def share_band(n: float, p_lo: float, p_hi: float, alpha: float,
               deff: float = 1.0) -> tuple[float, float]:
    """Band of a share measured on ``n`` samples whose true value is in ``[p_lo, p_hi]``.

    Parameters
    ----------
    n : float
        Number of samples.
    p_lo, p_hi : float
        The true share's range that counts as correct.
    alpha : float
        Two-sided probability that a correct share falls outside.
    deff : float, optional
        Design effect: ``n / deff`` independent samples.

    Returns
    -------
    tuple of float
        ``(lower, upper)`` bounds of the measured share.
    """
    m = max(int(n / max(deff, 1.0)), 1)
    lo = binom.ppf(alpha / 2.0, m, p_lo) / m
    hi = binom.isf(alpha / 2.0, m, p_hi) / m
    return float(max(lo - 0.5 / m, 0.0)), float(min(hi + 0.5 / m, 1.0))


def design_effect(hits, counts) -> float:
    """Variance of a pooled share between clusters (runs, seeds) over its binomial variance.

    Parameters
    ----------
    hits, counts : array_like
        Per cluster: samples inside and samples.

    Returns
    -------
    float
        At least 1; 1 with fewer than two clusters.
    """
    h = np.asarray(hits, float)
    n = np.asarray(counts, float)
    tot = n.sum()
    if h.size < 2 or tot <= 0:
        return 1.0
    p = h.sum() / tot
    var_binom = p * (1.0 - p) / tot if 0.0 < p < 1.0 else 1.0 / tot**2
    var_cluster = float(np.sum((h - p * n) ** 2)) / tot**2 * h.size / (h.size - 1)
    return max(var_cluster / var_binom, 1.0)


def mean_band(lo: float, hi: float, se: float, alpha: float) -> tuple[float, float]:
    """Band of a mean with standard error ``se`` whose true value is in ``[lo, hi]``."""
    z = z_two_sided(alpha)
    return lo - z * se, hi + z * se


@dataclass
class Criterion:
    """One acceptance criterion: a measured value and its bounds (None: open)."""

    name: str
    value: float
    lower: float | None = None
    upper: float | None = None
    claim: str = ""

    @property
    def passed(self) -> bool:
        """Whether the value lies inside the bounds (NaN never does)."""
        v = float(self.value)
        if math.isnan(v):
            return False
        return bool((self.lower is None or v >= self.lower)
                    and (self.upper is None or v <= self.upper))

    def line(self) -> str:
        """``PASS``/``FAIL``, the name, the value and the band."""
        lo = "-inf" if self.lower is None else _fmt(self.lower)
        hi = "inf" if self.upper is None else _fmt(self.upper)
        word = "in" if self.passed else "not in"
        text = f"{'PASS' if self.passed else 'FAIL'}  {self.name:58s} {_fmt(self.value)} " \
               f"{word} [{lo}, {hi}]"
        return text + (f"  ({self.claim})" if self.claim else "")


def _plain(x):
    """numpy scalars and arrays for json."""
    return x.tolist() if hasattr(x, "tolist") else str(x)


def _fmt(x: float) -> str:
    x = float(x)
    if x != 0.0 and (abs(x) < 1e-3 or abs(x) >= 1e5):
        return f"{x:.3g}"
    return f"{x:.4f}"


@dataclass
class Criteria:
    """The criteria of one validation run, reported together."""

    title: str
    items: list = field(default_factory=list)

    def add(self, name: str, value: float, lower: float | None = None,
            upper: float | None = None, claim: str = "") -> Criterion:
        """Add a criterion ``lower <= value <= upper``."""
        c = Criterion(name, float(value), None if lower is None else float(lower),
                      None if upper is None else float(upper), claim)
        self.items.append(c)
        return c

    def band(self, name: str, value: float, band: tuple, claim: str = "") -> Criterion:
        """Add a criterion with a ``(lower, upper)`` band."""
        return self.add(name, value, band[0], band[1], claim)

    @property
    def passed(self) -> bool:
        """Whether every criterion passed (and there is at least one)."""
        return bool(self.items) and all(c.passed for c in self.items)

    def report(self, json_path: str | None = None, figures: dict | None = None) -> int:
        """Print the criteria; write them (and ``figures``) to ``json_path`` as JSON.

        Returns
        -------
        int
            0 when every criterion passed, else 1 (the script's exit status).
        """
        print(f"\nacceptance criteria: {self.title}")
        for c in self.items:
            print("  " + c.line())
        bad = sum(not c.passed for c in self.items)
        if not self.items:
            print("VALIDATION FAILED: no criterion was checked")
        elif bad:
            print(f"VALIDATION FAILED: {bad} of {len(self.items)} criteria missed")
        else:
            print(f"validation passed: all {len(self.items)} criteria met")
        if json_path:
            with open(json_path, "w", encoding="utf-8") as fh:
                json.dump({"title": self.title, "passed": self.passed,
                           "criteria": [{**asdict(c), "passed": c.passed}
                                        for c in self.items],
                           "figures": figures or {}}, fh, indent=1, default=_plain)
        return 0 if self.passed else 1

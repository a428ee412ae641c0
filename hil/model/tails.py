"""Tail probabilities and quantiles of the t, F and binomial distributions: scipy.special's
functions, the ones scipy.stats evaluates, named for what the tests of the diagnosis ask.

Imports numpy and scipy.special only.
"""

from __future__ import annotations

from scipy.special import bdtrc, fdtrc, stdtrit


def t_quantile(probability: float, dof: float) -> float:
    """The ``probability`` quantile of Student's t with ``dof`` degrees of freedom
    (scipy.stats.t.ppf)."""
    return float(stdtrit(dof, probability))


def t_upper_quantile(tail: float, dof: float) -> float:
    """The t value exceeded with probability ``tail`` (scipy.stats.t.isf): by the
    distribution's symmetry, minus its ``tail`` quantile."""
    return float(-stdtrit(dof, tail))


def f_upper_tail(f: float, dfn: float, dfd: float) -> float:
    """P(F > ``f``) of Fisher's F(``dfn``, ``dfd``) (scipy.stats.f.sf)."""
    return float(fdtrc(dfn, dfd, f))


def binomial_upper_tail(k: float, n: int, p: float) -> float:
    """P(X > ``k``) of X ~ Binomial(``n``, ``p``) (scipy.stats.binom.sf); 1 for k < 0."""
    return float(bdtrc(k, n, p))


__all__ = ["binomial_upper_tail", "f_upper_tail", "t_quantile", "t_upper_quantile"]

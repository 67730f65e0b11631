"""Why a pair is doubtful: the ``doubt`` column of a pairs table.

A doubtful pair (a likely mis-pair, a pair without a usable measurement) is
left out of the size-magnification fit and reported untested, with its
reason. The reasons are an object array of strings, ``""`` for a pair
without doubt; every check adds its reason to the pairs that have none yet,
so a pair keeps the first reason it was given (the pairing's, then the
photometry's, then those of :func:`~lensdual.duality.check_duality`).
"""

import numpy as np

__all__ = []


def no_doubts(n):
    """The reasons of ``n`` pairs without doubt."""
    return np.array([""] * n, dtype=object)


def doubts_of(tab, column="doubt"):
    """The reasons in the ``column`` of ``tab`` (absent, masked or None: no doubt)."""
    if column not in tab.colnames:
        return no_doubts(len(tab))
    col = tab[column]
    masked = np.ma.getmaskarray(col) if hasattr(col, "mask") else np.zeros(len(tab), bool)
    return np.array([str(d) if not m and d is not None and str(d) not in ("", "--") else ""
                     for d, m in zip(np.asarray(col, dtype=object), masked, strict=True)],
                    dtype=object)


def add_doubt(doubt, mask, reason):
    """Give the pairs of ``mask`` that have no reason yet ``reason`` (in place).

    ``reason`` is a string, or a function of the pair's index that returns one.
    """
    for k in np.flatnonzero(np.asarray(mask, dtype=bool) & (doubt == "")):
        doubt[k] = reason(k) if callable(reason) else reason
    return doubt

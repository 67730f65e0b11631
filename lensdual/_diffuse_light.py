"""Pairs whose two images sit on different diffuse light (private).

Lensing conserves surface brightness, so the arc's own light is the same under
both images of a pair. The photometry's fitted background under each image
(``bkg1_<band>``, ``bkg2_<band>`` of :func:`~lensdual.photometry.measure_pairs`)
therefore differs between the two images only by light that is not lensed
(intracluster light, a cluster member, a patch of emission in front of one
image) and noise. The intracluster and member light vary smoothly over a
constellation; a patch under one image does not. For each pair the
difference ``d = bkg1 - bkg2`` (the mean over the bands) is compared with a
plane in the L1 position fitted to the other pairs: its externally
studentized residual ``t`` follows Student's t with ``n - 4`` degrees of
freedom where the differences scatter normally about a plane. A pair whose
``|t|`` exceeds the two-sided quantile at :data:`DIFFUSE_LIGHT_ALPHA`,
Bonferroni-corrected over the ``n`` pairs, is doubtful: its flux ratio may
hold light that is not the source's.
"""

import numpy as np
from astropy import units as u
from scipy import stats

from ._doubts import add_doubt
from ._pairs_table import ARCS, bkg_col, x_col, y_col

__all__ = []

#: The false-alarm probability of the diffuse-light doubt per constellation,
#: two-sided, over all its pairs (Bonferroni).
DIFFUSE_LIGHT_ALPHA = 0.01
#: The parameters of the plane the differences are compared with.
_PLANE = 3
#: Fewest pairs for the comparison: two degrees of freedom left per fit.
MIN_DIFFUSE_PAIRS = _PLANE + 3


def studentized_plane_residuals(x, y, d):
    """Each ``d[k]`` against the least-squares plane in ``(x, y)`` of the others: its
    residual over its predictive error, ``s_(k) (1 + x_k^T (X_(k)^T X_(k))^-1 x_k)^1/2``
    with ``s_(k)`` the others' residual scatter (``n - 4`` degrees of freedom)."""
    x, y, d = (np.asarray(v, dtype=float) for v in (x, y, d))
    n = d.size
    design = np.column_stack([np.ones(n), x - x.mean(), y - y.mean()])
    t = np.full(n, np.nan)
    for k in range(n):
        others = np.arange(n) != k
        a, b = design[others], d[others]
        beta = np.linalg.lstsq(a, b, rcond=None)[0]
        r = b - a @ beta
        s2 = r @ r / (n - 1 - _PLANE)
        lever = design[k] @ np.linalg.solve(a.T @ a, design[k])
        t[k] = (d[k] - design[k] @ beta) / np.sqrt(s2 * (1.0 + lever))
    return t


def diffuse_light_threshold(n, alpha=DIFFUSE_LIGHT_ALPHA):
    """The ``|t|`` beyond which one of ``n`` pairs is doubtful: Student's t quantile at
    ``1 - alpha / (2 n)`` with ``n - 4`` degrees of freedom."""
    return float(stats.t.ppf(1.0 - alpha / (2 * n), n - 1 - _PLANE))


def _background_differences(measured, bands):
    """Per pair, the mean over the bands of ``bkg1 - bkg2``; a band whose unit cannot
    be converted to the first band's makes every band count in units of its own
    spread over the pairs (the median absolute deviation). None without the columns."""
    per_band = []
    for band in bands:
        names = [bkg_col(arc, band) for arc in ARCS]
        if all(name in measured.colnames for name in names):
            per_band.append(u.Quantity(measured[names[0]]) - u.Quantity(measured[names[1]]))
    if not per_band:
        return None
    unit = per_band[0].unit
    if all(q.unit.is_equivalent(unit) for q in per_band):
        values = np.array([q.to_value(unit) for q in per_band])
    else:
        values = np.array([q.value for q in per_band])
        mad = np.nanmedian(np.abs(values - np.nanmedian(values, axis=1, keepdims=True)),
                           axis=1, keepdims=True)
        values = np.where(mad > 0, values / np.where(mad > 0, mad, 1.0), np.nan)
    with np.errstate(invalid="ignore"):
        finite = np.isfinite(values)
        return np.where(finite.any(axis=0),
                        np.nansum(values, axis=0) / np.maximum(finite.sum(axis=0), 1), np.nan)


def doubt_diffuse_light(measured, bands, doubt, alpha=DIFFUSE_LIGHT_ALPHA):
    """Make doubtful (in place) the pairs whose images sit on different light that is
    not lensed, and add the column ``diffuse_light_t`` (NaN where not compared).

    Only pairs without a doubt and with the background under both images take part;
    with fewer than :data:`MIN_DIFFUSE_PAIRS` of them nothing is compared. Returns the
    summary for ``meta``: the pairs compared, ``alpha`` and the threshold (None when
    nothing was compared).
    """
    t = np.full(len(measured), np.nan)
    d = _background_differences(measured, bands)
    summary = {"alpha": alpha, "n_pairs": 0, "threshold": None}
    if d is not None:
        x = u.Quantity(measured[x_col(1)], u.arcsec).value
        y = u.Quantity(measured[y_col(1)], u.arcsec).value
        use = (doubt == "") & np.isfinite(d) & np.isfinite(x) & np.isfinite(y)
        n = int(use.sum())
        if n >= MIN_DIFFUSE_PAIRS:
            t[use] = studentized_plane_residuals(x[use], y[use], d[use])
            threshold = diffuse_light_threshold(n, alpha)
            summary.update(n_pairs=n, threshold=threshold)
            add_doubt(doubt, np.abs(np.nan_to_num(t)) > threshold, lambda k: (
                f"diffuse light differs between the images (t = {t[k]:.1f} against the "
                f"other pairs' plane; beyond {threshold:.1f}, the {100 * alpha:g} % level over "
                f"{n} pairs): light that is not lensed, e.g. a patch of emission under one "
                "image, may be in its flux ratio"))
    measured["diffuse_light_t"] = t
    return summary

"""Pairs whose two images sit on different diffuse light (private).

Lensing conserves surface brightness, so the arc's own light is the same under
both images of a pair. The photometry's fitted background under each image
(``bkg1_<band>``, ``bkg2_<band>`` of :func:`~lensdual.photometry.measure_pairs`)
therefore differs between the two images by light that is not lensed
(intracluster light, a cluster member, a patch of emission in front of one
image), by the part of the source's own flux that a PSF model slightly
unlike the source puts into the background (proportional to the flux), and
by noise. The intracluster and member light vary smoothly over a
constellation; a patch under one image does not. For each pair the
difference ``d = bkg1 - bkg2`` (the mean over the bands) is compared with the
least-squares fit, to the other pairs, of a plane in the L1 position plus a
multiple of the flux difference ``f1 - f2`` (the mean over the bands): its
externally studentized residual ``t`` follows Student's t with ``n - 5``
degrees of freedom where the differences scatter normally about that model.
A pair whose ``|t|`` exceeds the two-sided quantile at
:data:`DIFFUSE_LIGHT_ALPHA`, Bonferroni-corrected over the ``n`` pairs, has a
doubtful flux ratio (``flux_doubt``): it may hold light that is not the
source's. Its positions are not in doubt, so it stays in the geometry. A
sub-halo's magnification moves ``f1 - f2`` and, through the leak, ``d`` along
the fitted multiple, so it does not make a pair doubtful.
"""

import numpy as np
from astropy import units as u
from scipy import stats

from ._doubts import add_doubt, no_doubts
from ._pairs_table import ARCS, bkg_col, flux_col, x_col, y_col

__all__ = []

#: The false-alarm probability of the diffuse-light doubt per constellation,
#: two-sided, over all its pairs (Bonferroni).
DIFFUSE_LIGHT_ALPHA = 0.01
#: The parameters of the model the differences are compared with: a plane in the
#: L1 position and the flux difference's multiple.
_PARAMETERS = 4
#: Fewest pairs for the comparison: two degrees of freedom left per fit.
MIN_DIFFUSE_PAIRS = _PARAMETERS + 3


def studentized_residuals(design, d):
    """Each ``d[k]`` against the least-squares fit of ``design`` to the others: its
    residual over its predictive error, ``s_(k) (1 + x_k^T (X_(k)^T X_(k))^-1 x_k)^1/2``
    with ``s_(k)`` the others' residual scatter (``n - 1 - p`` degrees of freedom);
    NaN where the others do not determine the fit (collinear positions) or fit
    exactly."""
    design, d = np.asarray(design, dtype=float), np.asarray(d, dtype=float)
    n, p = design.shape
    t = np.full(n, np.nan)
    for k in range(n):
        others = np.arange(n) != k
        a, b = design[others], d[others]
        beta, _, rank, _ = np.linalg.lstsq(a, b, rcond=None)
        if rank < p:
            continue
        r = b - a @ beta
        s2 = r @ r / (n - 1 - p)
        lever = design[k] @ np.linalg.pinv(a.T @ a) @ design[k]
        if s2 > 0:
            t[k] = (d[k] - design[k] @ beta) / np.sqrt(s2 * (1.0 + lever))
    return t


def diffuse_light_threshold(n, alpha=DIFFUSE_LIGHT_ALPHA):
    """The ``|t|`` beyond which one of ``n`` pairs is doubtful: Student's t quantile at
    ``1 - alpha / (2 n)`` with ``n - 5`` degrees of freedom."""
    return float(stats.t.ppf(1.0 - alpha / (2 * n), n - 1 - _PARAMETERS))


def _differences(measured, bands):
    """Per pair, the mean over the bands of ``bkg1 - bkg2`` and of ``flux1 - flux2``, and
    the bands used: those with the backgrounds whose units convert to the first such
    band's (NaN for a pair that misses a band). None without the columns."""
    used, d, f = [], [], []
    for band in bands:
        names = [bkg_col(arc, band) for arc in ARCS]
        fluxes = [flux_col(arc, band) for arc in ARCS]
        if not all(name in measured.colnames for name in names + fluxes):
            continue
        db = u.Quantity(measured[names[0]]) - u.Quantity(measured[names[1]])
        fb = u.Quantity(measured[fluxes[0]]) - u.Quantity(measured[fluxes[1]])
        if d and not (db.unit.is_equivalent(d[0].unit) and fb.unit.is_equivalent(f[0].unit)):
            continue
        used.append(band)
        d.append(db if not d else db.to(d[0].unit))
        f.append(fb if not f else fb.to(f[0].unit))
    if not used:
        return None
    # a pair that misses a band has NaN: every pair's mean is over the same bands
    return (np.mean([q.value for q in d], axis=0), np.mean([q.value for q in f], axis=0),
            used)


def doubt_diffuse_light(measured, bands, doubt, alpha=DIFFUSE_LIGHT_ALPHA):
    """Add the columns ``flux_doubt`` (why a pair's flux ratio is doubtful: its images
    sit on different light that is not lensed; "" where not) and ``diffuse_light_t``
    (NaN where not compared) to ``measured``.

    Only pairs without a ``doubt`` and with the backgrounds and fluxes of every band
    used take part; with fewer than :data:`MIN_DIFFUSE_PAIRS` of them nothing is
    compared. Returns the summary for ``meta``: the pairs compared, the bands,
    ``alpha`` and the threshold (None when nothing was compared).
    """
    t = np.full(len(measured), np.nan)
    flux_doubt = no_doubts(len(measured))
    found = _differences(measured, bands)
    summary = {"alpha": alpha, "n_pairs": 0, "bands": [], "threshold": None}
    if found is not None:
        d, f, used = found
        x = u.Quantity(measured[x_col(1)], u.arcsec).value
        y = u.Quantity(measured[y_col(1)], u.arcsec).value
        ok = (doubt == "") & np.isfinite(d) & np.isfinite(f) & np.isfinite(x) & np.isfinite(y)
        n = int(ok.sum())
        if n >= MIN_DIFFUSE_PAIRS:
            xs, ys, fs = x[ok], y[ok], f[ok]
            scale = np.std(fs) if np.std(fs) > 0 else 1.0
            design = np.column_stack([np.ones(n), xs - xs.mean(), ys - ys.mean(),
                                      (fs - fs.mean()) / scale])
            with np.errstate(invalid="ignore", divide="ignore"):
                t[ok] = studentized_residuals(design, d[ok])
            threshold = diffuse_light_threshold(n, alpha)
            summary.update(n_pairs=n, bands=list(used), threshold=threshold)
            add_doubt(flux_doubt, np.abs(np.nan_to_num(t)) > threshold, lambda k: (
                f"diffuse light differs between the images (t = {t[k]:.1f} against the "
                f"other pairs' model; beyond {threshold:.1f}, the {100 * alpha:g} % level over "
                f"{n} pairs): light that is not lensed, e.g. a patch of emission under one "
                "image, may be in its flux ratio"))
    measured["flux_doubt"] = flux_doubt.astype(str)
    measured["diffuse_light_t"] = t
    return summary

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
difference ``d = bkg1 - bkg2`` (the mean over the bands measured under both
its images) is compared with the least-squares fit, to the other pairs
measured in those bands, of a plane in the L1 position plus a multiple of the
flux difference ``f1 - f2`` (the mean over the same bands): its
externally studentized residual ``t`` follows Student's t with ``n - 5``
degrees of freedom (``n`` the pairs of that fit) where the differences scatter
normally about that model. A pair whose ``|t|`` exceeds the two-sided
quantile at :data:`DIFFUSE_LIGHT_ALPHA`, Bonferroni-corrected over all the
pairs compared, has a
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


def diffuse_light_threshold(n, alpha=DIFFUSE_LIGHT_ALPHA, n_fit=None):
    """The ``|t|`` beyond which one of ``n`` pairs is doubtful: Student's t quantile at
    ``1 - alpha / (2 n)`` with ``n_fit - 5`` degrees of freedom (``n_fit``, the pairs
    of its comparison, defaults to ``n``)."""
    n_fit = n if n_fit is None else n_fit
    return float(stats.t.ppf(1.0 - alpha / (2 * n), n_fit - 1 - _PARAMETERS))


def _differences(measured, bands):
    """Per band (rows) and pair (columns), ``bkg1 - bkg2`` and ``flux1 - flux2``, and
    the bands used: those with the backgrounds whose units convert to the first such
    band's. None without the columns."""
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
    return np.array([q.value for q in d]), np.array([q.value for q in f]), used


def _mix_residuals(mix, have, candidates, d, f, x, y):
    """The studentized residuals of the pairs measured in exactly the bands ``mix``
    (``(targets, t, n_fit)``): each pair's mean over ``mix`` against the fit to every
    other candidate pair measured in at least those bands; None with too few."""
    members = candidates & have[mix].all(axis=0)
    targets = candidates & (have == mix[:, None]).all(axis=0)
    n_fit = int(members.sum())
    if n_fit < MIN_DIFFUSE_PAIRS:
        return None
    dm, fm = d[mix][:, members].mean(axis=0), f[mix][:, members].mean(axis=0)
    xs, ys = x[members], y[members]
    scale = np.std(fm) if np.std(fm) > 0 else 1.0
    design = np.column_stack([np.ones(n_fit), xs - xs.mean(), ys - ys.mean(),
                              (fm - fm.mean()) / scale])
    with np.errstate(invalid="ignore", divide="ignore"):
        t = studentized_residuals(design, dm)
    return targets, t[targets[members]], n_fit


def doubt_diffuse_light(measured, bands, doubt, alpha=DIFFUSE_LIGHT_ALPHA):
    """Add the columns ``flux_doubt`` (why a pair's flux ratio is doubtful: its images
    sit on different light that is not lensed; "" where not) and ``diffuse_light_t``
    (NaN where not compared) to ``measured``.

    Only pairs without a ``doubt`` take part, each in the bands where both its
    backgrounds and fluxes were measured: its difference is the mean over those
    bands, compared with the fit to the other pairs measured in them (a pair whose
    fit failed in one band is compared in the others). A comparison needs
    :data:`MIN_DIFFUSE_PAIRS` pairs; the Bonferroni correction is over every pair
    compared. Returns the summary for ``meta``: the pairs compared, those compared
    in fewer than all the bands, the bands, ``alpha`` and the threshold of the
    pairs compared in every band (None when nothing was compared).
    """
    t = np.full(len(measured), np.nan)
    n_fit = np.zeros(len(measured), dtype=int)
    flux_doubt = no_doubts(len(measured))
    found = _differences(measured, bands)
    summary = {"alpha": alpha, "n_pairs": 0, "n_pairs_fewer_bands": 0, "bands": [],
               "threshold": None}
    if found is not None:
        d, f, used = found
        x = u.Quantity(measured[x_col(1)], u.arcsec).value
        y = u.Quantity(measured[y_col(1)], u.arcsec).value
        have = np.isfinite(d) & np.isfinite(f)
        candidates = (doubt == "") & have.any(axis=0) & np.isfinite(x) & np.isfinite(y)
        for mix in np.unique(have[:, candidates].T, axis=0):
            found_mix = _mix_residuals(mix, have, candidates, d, f, x, y)
            if found_mix is not None:
                targets, t[targets], n_fit[targets] = found_mix
        compared = np.isfinite(t) | (n_fit > 0)
        n = int(compared.sum())
        if n:
            thresholds = np.array([diffuse_light_threshold(n, alpha, m) if m else np.inf
                                   for m in n_fit])
            full = compared & have.all(axis=0)
            summary.update(n_pairs=n, n_pairs_fewer_bands=int((compared & ~full).sum()),
                           bands=list(used),
                           threshold=(float(thresholds[full][0]) if full.any() else None))
            add_doubt(flux_doubt, np.abs(np.nan_to_num(t)) > thresholds, lambda k: (
                f"diffuse light differs between the images (t = {t[k]:.1f} against the "
                f"other pairs' model; beyond {thresholds[k]:.1f}, the {100 * alpha:g} % level "
                f"over {n} pairs): light that is not lensed, e.g. a patch of emission under "
                "one image, may be in its flux ratio"))
    measured["flux_doubt"] = flux_doubt.astype(str)
    measured["diffuse_light_t"] = t
    return summary

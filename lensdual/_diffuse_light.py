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
difference ``d = bkg1 - bkg2`` (the mean over bands measured under both its
images: all of them, unless fewer give a fit of more pairs that is expected
to see light of one colour better) is compared with the least-squares fit, to
the other pairs measured in those bands, of a plane in the L1 position plus a
multiple of the flux difference ``f1 - f2`` (the mean over the same bands): its
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

import itertools

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


def _feasible_sets(have, candidates):
    """Per pair, the subsets of the bands it was measured in (tuples of band rows, most
    bands first) whose fit, the candidate pairs measured in at least those bands, has
    :data:`MIN_DIFFUSE_PAIRS` pairs, with that number; empty for a pair not compared."""
    out = [[] for _ in range(have.shape[1])]
    for k in np.flatnonzero(candidates):
        own = np.flatnonzero(have[:, k]).tolist()
        for size in range(len(own), 0, -1):
            for subset in itertools.combinations(own, size):
                n_fit = int((candidates & have[list(subset)].all(axis=0)).sum())
                if n_fit >= MIN_DIFFUSE_PAIRS:
                    out[k].append((subset, n_fit))
    return out


def _band_choice(feasible, n_compared, alpha):
    """The subset with the largest ``sqrt(bands) / threshold``: the expected ``t`` of
    light of one colour, in bands of equal noise, over its critical value (the first
    of equal ones: more bands). It depends on which pairs were measured, not on their
    values."""
    scores = [np.sqrt(len(subset)) / diffuse_light_threshold(n_compared, alpha, n_fit)
              for subset, n_fit in feasible]
    return feasible[int(np.argmax(scores))]


def _subset_residuals(subset, have, candidates, d, f, x, y):
    """The studentized residuals of every candidate pair measured in at least the bands
    ``subset`` (``(members, t)``): each one's mean over ``subset`` against the fit to
    the others."""
    rows = list(subset)
    members = candidates & have[rows].all(axis=0)
    n_fit = int(members.sum())
    dm, fm = d[rows][:, members].mean(axis=0), f[rows][:, members].mean(axis=0)
    xs, ys = x[members], y[members]
    scale = np.std(fm) if np.std(fm) > 0 else 1.0
    design = np.column_stack([np.ones(n_fit), xs - xs.mean(), ys - ys.mean(),
                              (fm - fm.mean()) / scale])
    with np.errstate(invalid="ignore", divide="ignore"):
        return members, studentized_residuals(design, dm)


def doubt_diffuse_light(measured, bands, doubt, alpha=DIFFUSE_LIGHT_ALPHA):
    """Add the columns ``flux_doubt`` (why a pair's flux ratio is doubtful: its images
    sit on different light that is not lensed; "" where not) and ``diffuse_light_t``
    (NaN where not compared) to ``measured``.

    Only pairs without a ``doubt`` take part, each in bands where both its
    backgrounds and fluxes were measured (:func:`_band_choice`: all of them, unless
    fewer give a fit of more pairs that is expected to see light of one colour
    better): its difference is the mean over those bands, compared with the fit
    to the other pairs measured in them. A fit needs :data:`MIN_DIFFUSE_PAIRS`
    pairs; the Bonferroni correction is over every pair compared. Returns the
    summary for ``meta``: the pairs compared, those compared in fewer bands than
    they were measured in or than the bands used, the bands used, ``alpha`` and
    the threshold applied to the most pairs (None when nothing was compared).
    """
    t = np.full(len(measured), np.nan)
    thresholds = np.full(len(measured), np.inf)
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
        feasible = _feasible_sets(have, candidates)
        n = sum(bool(options) for options in feasible)
        if n:
            chosen = [_band_choice(options, n, alpha)[0] if options else None
                      for options in feasible]
            for subset in sorted({c for c in chosen if c is not None}):
                members, t_all = _subset_residuals(subset, have, candidates, d, f, x, y)
                targets = np.array([c == subset for c in chosen])
                t[targets] = t_all[targets[members]]
                thresholds[targets] = diffuse_light_threshold(n, alpha,
                                                              int(members.sum()))
            compared = np.array([c is not None for c in chosen])
            sizes = np.array([len(c) if c is not None else 0 for c in chosen])
            in_bands = sorted({b for c in chosen if c is not None for b in c})
            values, counts = np.unique(thresholds[compared], return_counts=True)
            summary.update(
                n_pairs=n, bands=[used[b] for b in in_bands],
                n_pairs_fewer_bands=int((compared & ((sizes < have.sum(axis=0))
                                                     | (sizes < len(in_bands)))).sum()),
                threshold=float(values[np.argmax(counts)]))
            add_doubt(flux_doubt, np.abs(np.nan_to_num(t)) > thresholds, lambda k: (
                f"diffuse light differs between the images (t = {t[k]:.1f} against the "
                f"other pairs' model; beyond {thresholds[k]:.1f}, the {100 * alpha:g} % level "
                f"over {n} pairs): light that is not lensed, e.g. a patch of emission under "
                "one image, may be in its flux ratio"))
    measured["flux_doubt"] = flux_doubt.astype(str)
    measured["diffuse_light_t"] = t
    return summary

"""Validation of the size-magnification estimators against injected truth.

Reproduces the paper's Sect. 5.2.1 (Fig. 6: the SMACS0723 analogue with and
without cluster members) and App. B (Figs. 10-11: a grid of constellation
sizes and magnification ratios), for the 2v, Quad and second-order Quad
estimators.
"""

import warnings

import numpy as np
from astropy import units as u
from astropy.table import QTable, vstack

from .._pairs_table import arc_xy
from .._validation import as_int
from ..estimators import METHODS, relative_jacobian
from ..exceptions import EstimatorWarning
from .halos import elliptical_nfw_halo
from .lens_system import LensSystem
from .scenarios import smacs0723_analog

__all__ = [
    "estimator_errors",
    "cusp_lens",
    "pair_placements",
    "appendix_b_grid",
    "analog_errors",
    "summarize_errors",
]

DEFAULT_METHODS = ("2v", "quad", "quad2")


def _check_methods(methods):
    methods = [methods] if isinstance(methods, str) else list(methods)
    bad = [m for m in methods if m not in METHODS]
    if bad or not methods:
        raise ValueError(f"methods must be a non-empty list drawn from {sorted(METHODS)}, "
                         f"got {methods!r}")
    return methods


def estimator_errors(pairs, methods=DEFAULT_METHODS, *, position_noise=0 * u.arcsec,
                     seed=None):
    """Fractional error of each estimator on a simulated pairs table.

    Parameters
    ----------
    pairs : `~astropy.table.QTable`
        A pairs table with the truth column ``mu_true`` (e.g. from
        :meth:`LensSystem.constellation`).
    methods : sequence of str
        Estimators to run.
    position_noise : `~astropy.units.Quantity`
        Gaussian noise added to every position of both arcs before estimating
        (one realisation, the same for all methods); 0 measures the
        estimators' own (systematic) error.
    seed : int, `numpy.random.Generator` or None
        Seed of the position noise.

    Returns
    -------
    table : `~astropy.table.QTable`
        ``pair_id``, ``mu_true`` and, per method, ``mu_size_<method>`` and
        ``frac_err_<method>`` = ``mu_size / mu_true - 1``.
    """
    methods = _check_methods(methods)
    if "mu_true" not in pairs.colnames:
        raise ValueError("pairs must have the truth column 'mu_true' (a simulated table)")
    rng = np.random.default_rng(seed)
    sig = u.Quantity(position_noise, u.arcsec).value
    t1, t2 = arc_xy(pairs, 1), arc_xy(pairs, 2)
    t1 = t1 + sig * rng.standard_normal(t1.shape)
    t2 = t2 + sig * rng.standard_normal(t2.shape)
    out = QTable()
    out["pair_id"] = pairs["pair_id"]
    out["mu_true"] = np.asarray(pairs["mu_true"], dtype=float)
    for method in methods:
        with warnings.catch_warnings():
            # quad2's fallback on small constellations is expected here
            warnings.simplefilter("ignore", EstimatorWarning)
            jac = relative_jacobian(t1 * u.arcsec, t2 * u.arcsec, method)
        mu = np.abs(np.linalg.det(jac))
        out[f"mu_size_{method}"] = mu
        out[f"frac_err_{method}"] = mu / out["mu_true"] - 1
    out.meta["methods"] = methods
    out.meta["position_noise"] = position_noise
    return out


def cusp_lens(*, axis_ratio=0.7):
    """The fiducial lens of App. B: an elliptical NFW cluster with marked cusps.

    M200 = 5e14 Msun, c = 9.6 (as the SMACS0723 analogue), axis ratio 0.7,
    z = 0.39 / 2.2: a tangential caustic about 12 x 9 arcsec with four cusps.

    Parameters
    ----------
    axis_ratio : float
        Axis ratio of the halo (default 0.7).

    Returns
    -------
    system : `LensSystem`
    """
    main = elliptical_nfw_halo(5e14 * u.Msun, 9.6, axis_ratio=axis_ratio, z_lens=0.39,
                               z_source=2.2)
    return LensSystem([main], z_lens=0.39, z_source=2.2)


def _pair_ratios(images, n_candidates):
    """Per candidate source: (ratio, bright image xy, faint image xy) of its pairs.

    Pairs are the opposite-parity pairs among the three most magnified images
    of each source; ratio = mu_faint / mu_bright (in [-1, 0)).
    """
    out = []
    src = np.asarray(images["source"])
    mu_all = np.asarray(images["magnification"], dtype=float)
    xy_all = np.column_stack([images["x"].to_value(u.arcsec), images["y"].to_value(u.arcsec)])
    for i in range(n_candidates):
        idx = np.flatnonzero(src == i)
        idx = idx[np.argsort(-np.abs(mu_all[idx]))][:3]
        for a in range(len(idx)):
            for b in range(a + 1, len(idx)):
                ia, ib = idx[a], idx[b]
                if np.sign(mu_all[ia]) == np.sign(mu_all[ib]):
                    continue
                out.append((i, mu_all[ib] / mu_all[ia], ia, ib))
    return out, xy_all, mu_all


def pair_placements(system, target_ratios, *, margin=0.25 * u.arcsec, n_candidates=300,
                    caustic_kwargs=None):
    """Source centres whose images form an arc pair of a given magnification ratio.

    Candidate centres lie inside the tangential caustic, at least ``margin``
    from it (the caustic moved inwards by 1 to 4 margins); for each, the
    opposite-parity pairs among its three most magnified images are
    considered, and for every target the (centre, pair) with the closest
    ratio ``mu_faint / mu_bright`` is returned.

    Parameters
    ----------
    system : `LensSystem`
        The lens.
    target_ratios : array_like
        Wanted signed ratios ``mu_faint / mu_bright`` (in ``[-1, 0)``).
    margin : `~astropy.units.Quantity`
        Least distance of a centre from the caustic (default 0.25 arcsec).
    n_candidates : int
        Points of the caustic used to make candidate centres (default 300).
    caustic_kwargs : dict, optional
        Arguments of :meth:`LensSystem.critical_curves` (default a 40 arcsec
        half width at 0.1 arcsec).

    Returns
    -------
    placements : `~astropy.table.QTable`
        ``target_ratio``, ``ratio`` (achieved), ``centre`` (2,), and
        ``reference`` (2, 2): the positive- and negative-parity images, for
        :meth:`LensSystem.constellation`'s ``reference``.
    """
    kw = {"half_width": 40 * u.arcsec, "grid_spacing": 0.1 * u.arcsec}
    kw.update(caustic_kwargs or {})
    curves = system.critical_curves(**kw)
    radii = [np.max(np.hypot(*c.to_value(u.arcsec).T)) for c in curves]
    caustic = system.ray_shoot(curves[int(np.argmax(radii))]).to_value(u.arcsec)
    from matplotlib.path import Path
    from scipy.spatial import cKDTree

    dmin = u.Quantity(margin, u.arcsec).value
    centre0 = caustic.mean(axis=0)
    rel = caustic[:: max(1, len(caustic) // n_candidates)] - centre0
    r = np.hypot(*rel.T)
    # move inwards by 1-4 margins; keep points inside the caustic and at least
    # one margin from it (near a cusp a single step lands next to the other fold)
    cand = np.vstack([centre0 + rel * (1 - f * dmin / r)[:, None] for f in (1, 1.5, 2, 3, 4)])
    dist = cKDTree(caustic).query(cand)[0]
    cand = cand[Path(caustic).contains_points(cand) & (dist >= dmin)]
    images = system.solve_images(cand * u.arcsec)
    pairs, xy, mu = _pair_ratios(images, len(cand))
    ratios = np.array([p[1] for p in pairs])
    rows = []
    for target in np.atleast_1d(target_ratios):
        k = int(np.argmin(np.abs(ratios - target)))
        i, ratio, ia, ib = pairs[k]
        pos, neg = (ia, ib) if mu[ia] > 0 else (ib, ia)
        rows.append((float(target), float(ratio), cand[i], np.vstack([xy[pos], xy[neg]])))
    tab = QTable(rows=rows, names=("target_ratio", "ratio", "centre", "reference"))
    tab["centre"].unit = u.arcsec
    tab["reference"].unit = u.arcsec
    return tab


def appendix_b_grid(n_sources=(10, 20, 30), target_ratios=(-1.0, -0.65, -0.3), *,
                    methods=DEFAULT_METHODS, sigma=0.06 * u.arcsec, margin=0.25 * u.arcsec,
                    position_noise=0 * u.arcsec, system=None, seed=0):
    """The estimator-performance grid of the paper's App. B (Figs. 10 and 11).

    For every target magnification ratio a source centre is placed (see
    :func:`pair_placements`) on the fiducial :func:`cusp_lens`; for every
    constellation size, point sources are drawn from a Gaussian of ``sigma``
    around it until ``n`` of them are imaged on both arcs, and every
    estimator is run on the pairs.

    Parameters
    ----------
    n_sources : sequence of int
        Constellation sizes (default 10, 20, 30).
    target_ratios : sequence of float
        Magnification ratios of the panels (default -1, -0.65, -0.3).
    methods : sequence of str
        Estimators to run.
    sigma : `~astropy.units.Quantity`
        Spread of the sources around the centre (default 0.06 arcsec).
    margin : `~astropy.units.Quantity`
        See :func:`pair_placements`.
    position_noise : `~astropy.units.Quantity`
        See :func:`estimator_errors`.
    system : `LensSystem`, optional
        The lens (default :func:`cusp_lens`).
    seed : int
        Seed of the source draws and the noise.

    Returns
    -------
    table : `~astropy.table.QTable`
        One row per pair and panel: ``n_sources``, ``target_ratio``,
        ``ratio`` (the pair's true signed ratio ``mu(L1) / mu(L2)`` oriented
        as fainter over brighter), ``mu_true`` and ``frac_err_<method>``.
    """
    methods = _check_methods(methods)
    system = system or cusp_lens()
    rng = np.random.default_rng(seed)
    sig = u.Quantity(sigma, u.arcsec).value
    placements = pair_placements(system, target_ratios, margin=margin)
    rows = []
    for place in placements:
        centre = place["centre"].to_value(u.arcsec)
        for n in n_sources:
            n = as_int(n, "n_sources", minimum=3)
            beta = centre + sig * rng.standard_normal((int(1.5 * n) + 5, 2))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # sources off the arcs are expected
                pairs = system.constellation(beta * u.arcsec, reference=place["reference"])
            pairs = pairs[:n]
            errs = estimator_errors(pairs, methods, position_noise=position_noise, seed=rng)
            signed = np.asarray(pairs["mu1"] / pairs["mu2"])
            errs["ratio"] = np.where(np.abs(signed) > 1, 1 / signed, signed)
            errs["n_sources"] = n
            errs["target_ratio"] = place["target_ratio"]
            rows.append(errs)
    table = vstack(rows, metadata_conflicts="silent")
    table.meta["methods"] = methods
    table.meta["placements"] = placements
    return table


def analog_errors(*, perturbers=False, seeds=range(10), methods=DEFAULT_METHODS,
                  position_noise=0 * u.arcsec):
    """Estimator errors on the SMACS0723 analogue over several constellations (Fig. 6).

    Parameters
    ----------
    perturbers : bool
        Add the analogue's perturbing members (default False).
    seeds : iterable of int
        One constellation (and analogue) per seed.
    methods : sequence of str
        Estimators to run.
    position_noise : `~astropy.units.Quantity`
        See :func:`estimator_errors`.

    Returns
    -------
    table : `~astropy.table.QTable`
        :func:`estimator_errors`' columns for every seed, plus ``seed``.
    """
    rows = []
    for seed in seeds:
        system = smacs0723_analog(perturbers=perturbers, seed=seed)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            pairs = system.constellation(seed=seed)
        errs = estimator_errors(pairs, methods, position_noise=position_noise, seed=seed)
        errs["seed"] = seed
        rows.append(errs)
    table = vstack(rows, metadata_conflicts="silent")
    table.meta["methods"] = list(methods)
    return table


def summarize_errors(table, by=("n_sources", "target_ratio")):
    """Per group and method: median, 95th percentile and maximum of the absolute error.

    Also the 16-84 % half width of the signed error (``half_width_68``).

    Parameters
    ----------
    table : `~astropy.table.QTable`
        Output of :func:`estimator_errors`, :func:`appendix_b_grid` or
        :func:`analog_errors`.
    by : sequence of str
        Grouping columns (empty: one group).

    Returns
    -------
    summary : `~astropy.table.QTable`
        The ``by`` columns, ``method``, ``n``, ``median_abs_err``,
        ``half_width_68``, ``abs_err_95`` and ``max_abs_err``.
    """
    methods = table.meta["methods"]
    by = [c for c in by if c in table.colnames]
    groups = table.group_by(by) if by else [table]
    keys = groups.groups.keys if by else [()]
    rows = []
    for key, grp in zip(keys, groups.groups if by else groups, strict=True):
        for method in methods:
            e = np.asarray(grp[f"frac_err_{method}"], dtype=float)
            e = e[np.isfinite(e)]
            p16, p84 = np.percentile(e, [16, 84])
            rows.append(tuple(key[c] for c in by) + (
                method, len(e), float(np.median(np.abs(e))), 0.5 * float(p84 - p16),
                float(np.percentile(np.abs(e), 95)), float(np.max(np.abs(e)))))
    names = tuple(by) + ("method", "n", "median_abs_err", "half_width_68", "abs_err_95",
                         "max_abs_err")
    return QTable(rows=rows, names=names)

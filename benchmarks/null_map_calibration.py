"""Do the null calibration's rates hold? Its empirical p-values on clean constellations.

Run on demand (minutes per cell)::

    python benchmarks/null_map_calibration.py [--families smacs_analog galaxy_fold]
        [--n-sources 12 20] [--sigma-mas 10] [--n-constellations 30]
        [--n-realisations 400] [--map tps|polynomial]

For every cell (family, number of sources, position noise), clean
constellations of the family get noise as a user's table has
(:func:`~lensdual.simulation.noisy_constellation`, 2 % flux noise per image
and band, two bands), and :func:`~lensdual.duality.null_calibration` ranks
their pairs against null realisations of a smooth map fitted to them. No pair
carries an anomaly, so where the null's map behaves like the lens its
empirical p-values are uniform: the fraction at or below 1 % and 5 % is then
1 % and 5 %, and the null's own false-alarm rate equals the rate at which
:func:`~lensdual.duality.check_duality` flags these clean pairs. Reported per
cell: tested pairs, the observed flag rate at SNR 3, the null's mean
false-alarm rate, the fractions of empirical p-values at or below 1 % and 5 %
(with their binomial 95 % intervals), the median chi2/dof of the null map, its
median effective degrees of freedom per coordinate and how many constellations
warned that the null map does not follow the data.

``--demo-seeds N`` runs the demo's scenario instead (the SMACS0723 analogue
without a sub-halo, 12 sources, two-band mock images through the real-data
pipeline with PSF astrometry errors as sigma_pos), seeds 0 to N - 1.

``--map polynomial`` runs the global polynomial map of earlier releases (the
lowest degree up to 4 within the errors, at least two pairs per coefficient),
kept here as the reference the spline map replaced; ``--kernel tps`` and
``--criterion gml`` run the thin-plate kernel and the marginal-likelihood
smoothing that were compared with the default (quintic kernel, UBRE).
"""

import argparse
import time
import warnings

import numpy as np
from _shared_data import use_shared_data
from astropy import units as u
from scipy.stats import beta, chi2

from lensdual import _null_map, duality
from lensdual._null_map import NullMap
from lensdual.estimators.core import _poly_terms
from lensdual.exceptions import LensdualWarning
from lensdual.simulation import clean_constellation, noisy_constellation

#: The test these records were made with: the geometric test with the linearised
#: SNR (the default until the joint test became it).
GEOMETRIC = {"test": "geometric", "snr_definition": "log"}


def polynomial_map(t1, t2, sigma, alpha=0.05):
    """The earlier null map: a global polynomial, the lowest degree (1 to 4) whose
    weighted chi-square is consistent with the position errors at ``alpha``,
    with at least two pairs per coefficient."""
    n = t1.shape[0]
    centre = t2.mean(axis=0)
    scale = np.max(np.hypot(*(t2 - centre).T))
    u_ = (t2 - centre) / scale
    jnorm2 = 2.0
    best = None
    for degree in range(1, 5):
        f, fx, fy = _poly_terms(u_, degree)
        if n < 2 * f.shape[1]:
            break
        w = 1.0 / (sigma[0] ** 2 + sigma[1] ** 2 * 0.5 * jnorm2)
        sw = np.sqrt(w)[:, None]
        coef = np.linalg.lstsq(f * sw, t1 * sw, rcond=None)[0]
        resid = t1 - f @ coef
        chi = float((w[:, None] * resid**2).sum())
        dof = 2 * (n - f.shape[1])
        jac = np.stack([np.column_stack([fx @ coef[:, 0], fy @ coef[:, 0]]),
                        np.column_stack([fx @ coef[:, 1], fy @ coef[:, 1]])], axis=1) / scale
        jnorm2 = np.median((jac**2).sum(axis=(1, 2)))
        best = NullMap(f @ coef, jac, chi / dof, float(f.shape[1]),
                                f"a degree-{degree} polynomial", np.nan, w)
        if chi2.sf(chi, dof) >= alpha:
            break
    return best


def _interval(k, n):
    lo = beta.ppf(0.025, k, n - k + 1) if k > 0 else 0.0
    hi = beta.ppf(0.975, k + 1, n - k) if k < n else 1.0
    return lo, hi


def run_cell(family, n_sources, sigma_mas, n_constellations, n_realisations, seed0=5000):
    sigma = sigma_mas * u.mas
    flags = tested = 0
    far, p_emp, chi_dof, map_dof = [], [], [], []
    n_warned = 0
    k = 0
    seed = seed0
    while k < n_constellations:
        seed += 1
        try:
            clean = clean_constellation(family, n_sources, seed=seed)
        except ValueError:
            continue
        noisy = noisy_constellation(clean, sigma_pos=sigma, flux_rel_err=0.02, seed=seed + 1)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            null = duality.null_calibration(noisy, sigma_pos=sigma,
                                            n_realisations=n_realisations, seed=seed,
                                            **GEOMETRIC)
        n_warned += any(issubclass(w.category, LensdualWarning)
                        and "null map" in str(w.message) for w in caught)
        ok = np.asarray(null["tested"], dtype=bool)
        tested += int(ok.sum())
        flags += int((np.asarray(null["significance"])[ok] > 3.0).sum())
        far.append(null.meta["false_alarm_rate"] * ok.sum())
        p_emp.extend(np.asarray(null["p_value_empirical"])[ok])
        chi_dof.append(null.meta["map_chi2_dof"])
        map_dof.append(null.meta["map_dof"])
        k += 1
    return _summary(flags, tested, far, p_emp, chi_dof, map_dof, n_warned)


def run_demo_cell(n_seeds, n_realisations):
    """The same statistics on the demo's scenario without a sub-halo."""
    from lensdual.demo import DEMO_BANDS, simulate_demo
    from lensdual.pipeline import analyse
    from lensdual.simulation import render_mock_images

    flags = tested = 0
    far, p_emp, chi_dof, map_dof = [], [], [], []
    n_warned = 0
    for seed in range(n_seeds):
        system, truth = simulate_demo(subhalo="none", seed=seed)
        mocks = render_mock_images(system, bands=DEMO_BANDS, pairs=truth, seed=seed)
        images = {arc: dict(mocks.arc(arc)) for arc in ("L1", "L2")}
        psf = {band: np.asarray(mocks[("L1", band)].psf) for band in DEMO_BANDS}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = analyse(images, psf=psf, seed=seed, null_realisations=n_realisations,
                          **GEOMETRIC).result
        null = res.meta["duality"]["null_calibration"]
        ok = np.asarray(res["tested"], dtype=bool)
        tested += int(ok.sum())
        flags += int(np.asarray(res["anomalous"])[ok].sum())
        far.append(null["false_alarm_rate"] * ok.sum())
        p_emp.extend(np.asarray(res["p_value_empirical"])[ok])
        chi_dof.append(null["map_chi2_dof"])
        map_dof.append(null["map_dof"])
        n_warned += bool(null["map_interpolates"])
    return _summary(flags, tested, far, p_emp, chi_dof, map_dof, n_warned)


def _summary(flags, tested, far, p_emp, chi_dof, map_dof, n_warned):
    p_emp = np.asarray(p_emp)
    n = p_emp.size
    out = {"tested": tested, "flag_rate": flags / max(tested, 1),
           "null_rate": float(np.sum(far)) / max(tested, 1),
           "chi2_dof": float(np.median(chi_dof)), "map_dof": float(np.median(map_dof)),
           "warned": n_warned}
    for level in (0.01, 0.05):
        kk = int(np.sum(p_emp <= level))
        out[f"p{level}"] = (kk / max(n, 1), *_interval(kk, n))
    return out


def _row(name, n_src, sig, r, seconds):
    p1, p5 = r["p0.01"], r["p0.05"]
    return (f"{name} | {n_src} | {sig} | {r['tested']} | "
            f"{100 * r['flag_rate']:.2f} % | {100 * r['null_rate']:.2f} % | "
            f"{100 * p1[0]:.1f} % [{100 * p1[1]:.1f}, {100 * p1[2]:.1f}] | "
            f"{100 * p5[0]:.1f} % [{100 * p5[1]:.1f}, {100 * p5[2]:.1f}] | "
            f"{r['chi2_dof']:.2f} | {r['map_dof']:.1f} | {r['warned']} | {seconds:.0f}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--families", nargs="+", default=["smacs_analog", "galaxy_fold"])
    parser.add_argument("--n-sources", nargs="+", type=int, default=[12, 20])
    parser.add_argument("--sigma-mas", nargs="+", type=float, default=[10.0])
    parser.add_argument("--n-constellations", type=int, default=30)
    parser.add_argument("--n-realisations", type=int, default=400)
    parser.add_argument("--map", choices=("spline", "polynomial"), default="spline")
    parser.add_argument("--demo-seeds", type=int, default=0,
                        help="run the demo's scenario over this many seeds instead")
    parser.add_argument("--criterion", choices=("ubre", "gml"), default=None,
                        help="the spline map's smoothing criterion (default: the library's)")
    parser.add_argument("--kernel", choices=("tps", "quintic"), default=None,
                        help="the smooth map's kernel (default: the library's)")
    args = parser.parse_args(argv)
    use_shared_data()
    if args.map == "polynomial":
        duality._smooth_map = polynomial_map
    if args.criterion:
        _null_map.CRITERION = args.criterion
    if args.kernel:
        _null_map.KERNEL = args.kernel
    print(f"null map: {args.map} ({_null_map.KERNEL}, {_null_map.CRITERION}); "
          f"{args.n_constellations} constellations per cell, "
          f"{args.n_realisations} null realisations each, 2 % flux noise, 2 bands")
    print("family | sources | sigma (mas) | tested | flags at SNR 3 | null's rate | "
          "p_emp <= 1 % [95 %] | p_emp <= 5 % [95 %] | map chi2/dof | map dof | warned | s")
    if args.demo_seeds:
        t0 = time.perf_counter()
        r = run_demo_cell(args.demo_seeds, args.n_realisations)
        print(_row("demo (no sub-halo)", 12, "PSF fits", r, time.perf_counter() - t0))
        return
    for family in args.families:
        for n_src in args.n_sources:
            for sig in args.sigma_mas:
                t0 = time.perf_counter()
                r = run_cell(family, n_src, sig, args.n_constellations, args.n_realisations)
                print(_row(family, n_src, f"{sig:g}", r, time.perf_counter() - t0), flush=True)


if __name__ == "__main__":
    main()

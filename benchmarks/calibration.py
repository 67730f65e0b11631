"""Calibration suite of the duality test: pulls, false flags and power per regime.

Run on demand (minutes)::

    python benchmarks/calibration.py [--quick]

For every cell (lens family x position noise) many clean constellations
(no sub-halo, exact true positions from the lens, flux ratios equal to the
true magnification ratio with 1 % errors per image) get Gaussian position
noise, and each estimator is run on them. Reported per cell:

- ``ok``: fraction of pairs whose adaptive fit passed its chi-square test
  (the rest are "misfit": tested with misfit-scaled errors);
- ``ffr``: false-flag rate at SNR 3 (nominal 0.27 %);
- ``pull_med``, ``pull_w``: median and robust (16-84 %) half-width of
  ln(mu_size / mu_true) / sigma;
- ``bias``: median of ln(mu_size / mu_true);
- ``sig``: median sigma of ln mu_size;
- ``pow10``, ``pow25``, ``pow50``: fraction of pairs flagged when their
  L1 flux is raised by 10, 25, 50 % (an injected anomaly).

Families: the SMACS0723 analogue with its two members (resolvable sources
in the fold caustic), a galaxy-scale SIE + shear fold with a constellation
spanning ~1 arcsec of arc, and, where ``lensdual.simulation.families``
provides them, its families too.
"""

import argparse
import time
import warnings

import numpy as np
from astropy import units as u

from lensdual.duality import gaussian_p_value
from lensdual.estimators import size_magnification
from lensdual.simulation import LensComponent, LensSystem, smacs0723_analog

NOISE_MAS = (1, 2, 5, 10, 20)
FLUX_ERR = 0.01  # per image


def _resolvable(t1, t2, keep_max, min_sep=0.08):
    keep = []
    for i in range(len(t1)):
        if all(np.hypot(*(t1[i] - t1[j])) >= min_sep and np.hypot(*(t2[i] - t2[j])) >= min_sep
               for j in keep):
            keep.append(i)
        if len(keep) == keep_max:
            break
    return keep


def smacs_constellations(n_const, n_sources=25, seed=0):
    """Resolvable constellations on the SMACS0723 analogue's fold (members included)."""
    system = smacs0723_analog(perturbers=True)
    out = []
    for k in range(n_const):
        rng = np.random.default_rng(seed + k)
        beta = np.array([0.69, 6.99]) + rng.normal(0, 0.12, (200, 2))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            p = system.constellation(beta * u.arcsec)
        p = p[(p["n_images1"] == 1) & (p["n_images2"] == 1)]
        t1 = np.column_stack([p["x1"].value, p["y1"].value])
        t2 = np.column_stack([p["x2"].value, p["y2"].value])
        keep = _resolvable(t1, t2, n_sources)
        out.append((t1[keep], t2[keep], np.asarray(p["mu_true"])[keep]))
    return out


def galaxy_constellations(n_const, n_sources=14, seed=0):
    """A galaxy-scale SIE + shear fold; sources 4-30 mas inside the fold caustic."""
    from matplotlib.path import Path
    from scipy.spatial import cKDTree

    system = LensSystem([
        LensComponent("SIE", {"theta_E": 1.2, "e1": 0.12, "e2": 0.03, "center_x": 0.0,
                              "center_y": 0.0}),
        LensComponent("SHEAR", {"gamma1": 0.05, "gamma2": -0.03, "ra_0": 0.0, "dec_0": 0.0}),
    ], z_lens=0.5, z_source=2.0)
    curves = system.critical_curves(half_width=3 * u.arcsec, grid_spacing=0.01 * u.arcsec)
    crit = [c.to_value(u.arcsec) for c in curves]
    i = int(np.argmax([np.ptp(c[:, 0]) for c in crit]))
    crit = crit[i]
    caus = system.ray_shoot(curves[i]).to_value(u.arcsec)
    k = np.argmin(np.abs(np.arctan2(crit[:, 1], crit[:, 0]) - 1.0))
    bc, tc = caus[k], crit[k]
    path, tree = Path(caus), cKDTree(caus)
    lm, kw = system.lens_model, system.kwargs_lens
    out = []
    for c in range(n_const):
        rng = np.random.default_rng(seed + c)
        cand = bc + rng.uniform(-0.06, 0.06, (3000, 2))
        d = tree.query(cand)[0]
        cand = cand[path.contains_points(cand) & (d > 0.004) & (d < 0.03)][:8 * n_sources]
        im = system.solve_images(cand * u.arcsec)
        src = np.asarray(im["source"])
        xy = np.column_stack([im["x"].to_value(u.arcsec), im["y"].to_value(u.arcsec)])
        par = np.asarray(im["parity"])
        t1, t2 = [], []
        for j in range(len(cand)):
            kk = np.flatnonzero(src == j)
            if len(kk) not in (4, 5):
                continue
            o = np.argsort(np.hypot(*(xy[kk] - tc).T))[:2]
            if par[kk[o[0]]] == par[kk[o[1]]]:
                continue
            pos, neg = (o[0], o[1]) if par[kk[o[0]]] > 0 else (o[1], o[0])
            t1.append(xy[kk[pos]])
            t2.append(xy[kk[neg]])
        t1, t2 = np.array(t1), np.array(t2)
        keep = _resolvable(t1, t2, n_sources)
        t1, t2 = t1[keep], t2[keep]
        mu = np.abs(lm.magnification(*t1.T, kw) / lm.magnification(*t2.T, kw))
        out.append((t1, t2, mu))
    return out


def run_cell(constellations, sigma_mas, method, n_noise, seed=0):
    rng = np.random.default_rng(seed)
    err, sd, status = [], [], []
    sig = sigma_mas / 1000.0
    for t1, t2, mu in constellations:
        for _ in range(n_noise):
            o1 = t1 + sig * rng.standard_normal(t1.shape)
            o2 = t2 + sig * rng.standard_normal(t2.shape)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                tab = size_magnification(o1 * u.arcsec, o2 * u.arcsec, method,
                                         sigma_pos=sig * u.arcsec, n_bootstrap=200,
                                         seed=int(rng.integers(2**31)))
            err.append(np.log(np.asarray(tab["mu_size"]) / mu))
            sd.append(np.asarray(tab["ln_mu_size_err"]))
            status.append(np.asarray(tab["mu_size_status"]))
    err, sd, status = map(np.concatenate, (err, sd, status))
    flux_sd = np.sqrt(2) * FLUX_ERR
    ln_flux_noise = flux_sd * rng.standard_normal(err.size)
    tested = status != "failed"
    tot = np.hypot(sd, flux_sd)
    pull = err / sd
    out = {"n": int(tested.sum()), "ok": float(np.mean(status == "ok"))}
    snr0 = np.abs(ln_flux_noise - err) / tot
    out["ffr"] = float(np.mean(snr0[tested] > 3))
    q16, q50, q84 = np.percentile(pull[tested], [15.87, 50, 84.13])
    out.update(pull_med=q50, pull_w=0.5 * (q84 - q16), bias=float(np.median(err[tested])),
               sig=float(np.median(sd[tested])))
    for a in (0.10, 0.25, 0.50):
        snr = np.abs(np.log1p(a) + ln_flux_noise - err) / tot
        out[f"pow{int(a * 100)}"] = float(np.mean(snr[tested] > 3))
    out["nominal"] = float(gaussian_p_value(3.0))
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer constellations")
    parser.add_argument("--methods", default="adaptive,quad2")
    args = parser.parse_args(argv)
    n_const, n_noise = (6, 5) if args.quick else (12, 20)
    families = {
        "smacs_analog": smacs_constellations(n_const),
        "galaxy_sie_shear": galaxy_constellations(n_const),
    }
    try:
        from lensdual.simulation import families as fam
    except ImportError:
        fam = None
    if fam is not None:
        for name in fam.FAMILIES:
            if name in families:
                continue
            try:
                tabs = [fam.clean_constellation(name, 20, seed=s) for s in range(n_const)]
            except (FileNotFoundError, ValueError, RuntimeError) as exc:
                print(f"# {name}: skipped ({exc})")
                continue
            families[name] = [
                (np.column_stack([t["x1"].value, t["y1"].value]),
                 np.column_stack([t["x2"].value, t["y2"].value]),
                 np.asarray(t["mu_true"])) for t in tabs]
    cols = ("n", "ok", "ffr", "pull_med", "pull_w", "bias", "sig", "pow10", "pow25", "pow50")
    print("family method noise_mas " + " ".join(cols))
    for name, cons in families.items():
        for method in args.methods.split(","):
            for s in NOISE_MAS:
                t0 = time.perf_counter()
                r = run_cell(cons, s, method, n_noise)
                print(f"{name} {method} {s} " + " ".join(f"{r[c]:.4g}" for c in cols)
                      + f"  # {time.perf_counter() - t0:.0f} s", flush=True)


if __name__ == "__main__":
    main()

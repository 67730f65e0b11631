"""False flags and power of the duality test with the profile-likelihood SNR.

Run on demand (minutes)::

    python benchmarks/profile_snr_calibration.py [--families a,b] [--n-sources 20,40]
        [--noise 1,5,20] [--n-const 10] [--n-noise 10]

For every cell (lens family x sources x position noise), clean constellations
(:func:`lensdual.simulation.clean_constellation`, exact positions, flux
ratios equal to the true magnification ratio with 1 % errors per image) get
Gaussian position noise and the adaptive estimator runs on them, as in
``benchmarks/calibration.py``. Each tested pair ("ok" or "misfit") is
flagged at significance 3 by two SNRs of the same estimate:

- ``log``: ``|ln R - ln mu_size| / sqrt(err_flux^2 + err_size^2)``
  (``snr_definition="log"``);
- ``profile``: :func:`lensdual.duality.profile_snr`
  (``snr_definition="profile"``), from the Jacobian and its covariance;
- ``cons``: the smaller of the two (``snr_definition="conservative"``, the
  default with the adaptive estimator; with fewer than 13 sources, where the
  flux field predicts no pair, it is the default test).

Both use Student's t with the degrees of freedom of ``check_duality``.
Reported per cell: the false-flag rate of each with its one-sided 95 %
Clopper-Pearson limits (pooled pairs; nominal 0.27 %), and the power on a
25 % anomaly (the L1 flux raised by 25 %) and on a -20 % one (lowered).

With ``--jspace`` it checks instead the covariance ``jacobian_cov`` that
the profile SNR uses: for each constellation, ``--n-noise`` noise draws;
for each pair with an "ok" status in every draw, the empirical covariance
``S`` of the estimated Jacobian over the draws against the mean reported
``C``. Printed per cell: the median over pairs of the empirical variance of
``ln mu_size`` over the mean reported variance (the projection the default
SNR uses), and the median and 90th percentile of the smallest and largest
eigenvalues of ``C^-1 S`` (10th and 90th percentiles), and the same for
``S`` from as many Gaussian draws with covariance ``C``: their spread is
what the finite number of draws gives where ``C`` holds.
"""

import argparse
import warnings

import numpy as np
from _shared_data import use_shared_data
from astropy import units as u
from scipy.stats import beta as beta_dist

from lensdual.duality import _snr_dof, duality_significance, profile_snr
from lensdual.estimators import size_magnification
from lensdual.simulation import FAMILIES, clean_constellation

FLUX_ERR = 0.01  # per image
TESTABLE = ("ok", "misfit")
SNRS = ("log", "profile", "cons")


def _limits(k, n):
    lo = 0.0 if k == 0 else float(beta_dist.ppf(0.05, k, n - k + 1))
    hi = float(beta_dist.ppf(0.95, k + 1, n - k))
    return lo, hi


def _noisy_size(t1, t2, sig, rng):
    """The adaptive size_magnification table of one noise draw of both arcs."""
    o1 = t1 + sig * rng.standard_normal(t1.shape)
    o2 = t2 + sig * rng.standard_normal(t2.shape)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return size_magnification(o1 * u.arcsec, o2 * u.arcsec, "adaptive",
                                  sigma_pos=sig * u.arcsec)


def run_cell(family, n_sources, sigma_mas, n_const, n_noise, seed=0):
    """One cell's flags: a dict of boolean arrays over the tested pairs."""
    rng = np.random.default_rng(seed)
    sig = sigma_mas / 1000.0
    fl = np.sqrt(2.0) * FLUX_ERR
    out = {f"{d}_{a}": [] for d in SNRS for a in ("0", "p25", "m20")}
    for k in range(n_const):
        t = clean_constellation(family, n_sources, seed=seed + k)
        t1 = np.column_stack([t["x1"].to_value(u.arcsec), t["y1"].to_value(u.arcsec)])
        t2 = np.column_stack([t["x2"].to_value(u.arcsec), t["y2"].to_value(u.arcsec)])
        mu = np.asarray(t["mu_true"], dtype=float)
        for _ in range(n_noise):
            size = _noisy_size(t1, t2, sig, rng)
            sd = np.asarray(size["ln_mu_size_err"], dtype=float)
            dof = np.asarray(size["ln_mu_size_err_dof"], dtype=float)
            tot = np.hypot(sd, fl)
            tdof = _snr_dof(tot, sd, dof)
            tested = np.isin(np.asarray(size["mu_size_status"]), TESTABLE) & (tdof > 0)
            ln_size = np.log(np.asarray(size["mu_size"], dtype=float))
            noise = fl * rng.standard_normal(n_sources)
            for key, a in (("0", 0.0), ("p25", np.log(1.25)), ("m20", np.log(0.8))):
                ln_r = np.log(mu) + a + noise
                with np.errstate(invalid="ignore"):
                    snr = {"log": np.abs(ln_r - ln_size) / tot,
                           "profile": profile_snr(size, ln_r, np.full(n_sources, fl))}
                snr["cons"] = np.fmin(snr["log"], snr["profile"])
                for d, x in snr.items():
                    ok = tested & np.isfinite(x)
                    sig_ = duality_significance(np.where(ok, x, 0.0), np.where(ok, tdof, np.inf))
                    out[f"{d}_{key}"].append((sig_ > 3)[tested])
    return {k: np.concatenate(v) for k, v in out.items()}


def jspace_cell(family, n_sources, sigma_mas, n_const, n_noise, seed=0):
    """Per-pair ratios of the empirical to the reported (co)variance."""
    rng = np.random.default_rng(seed)
    sig = sigma_mas / 1000.0
    ratio_ln, eig_lo, eig_hi, ref_lo, ref_hi = [], [], [], [], []
    for k in range(n_const):
        t = clean_constellation(family, n_sources, seed=seed + k)
        t1 = np.column_stack([t["x1"].to_value(u.arcsec), t["y1"].to_value(u.arcsec)])
        t2 = np.column_stack([t["x2"].to_value(u.arcsec), t["y2"].to_value(u.arcsec)])
        jac, cov, ln_mu, ln_var, ok = [], [], [], [], np.ones(n_sources, bool)
        for _ in range(n_noise):
            size = _noisy_size(t1, t2, sig, rng)
            ok &= np.asarray(size["mu_size_status"]) == "ok"
            jac.append(np.asarray(size["jacobian"], dtype=float).reshape(-1, 4))
            cov.append(np.asarray(size["jacobian_cov"], dtype=float))
            ln_mu.append(np.log(np.asarray(size["mu_size"], dtype=float)))
            ln_var.append(np.asarray(size["ln_mu_size_err"], dtype=float) ** 2)
        jac, cov, ln_mu, ln_var = map(np.array, (jac, cov, ln_mu, ln_var))
        for i in np.flatnonzero(ok):
            ratio_ln.append(np.var(ln_mu[:, i], ddof=1) / np.mean(ln_var[:, i]))
            s_emp = np.cov(jac[:, i].T)
            c_mean = cov[:, i].mean(axis=0)
            w = np.linalg.eigvals(np.linalg.solve(c_mean, s_emp)).real
            eig_lo.append(w.min())
            eig_hi.append(w.max())
            # the same statistic where C holds: Gaussian draws with covariance C
            g = rng.multivariate_normal(np.zeros(4), c_mean, size=n_noise)
            w = np.linalg.eigvals(np.linalg.solve(c_mean, np.cov(g.T))).real
            ref_lo.append(w.min())
            ref_hi.append(w.max())
    return tuple(map(np.array, (ratio_ln, eig_lo, eig_hi, ref_lo, ref_hi)))


def _jspace(args):
    print("family n_sources noise_mas n_pairs var_ln_ratio_median "
          "eig_min_median/p10 eig_max_median/p90 (where C holds: eig_min_median/p10 "
          "eig_max_median/p90)")
    for fam in args.families.split(","):
        for n in map(int, args.n_sources.split(",")):
            for s in map(float, args.noise.split(",")):
                r, *eig = jspace_cell(fam, n, s, args.n_const, args.n_noise, args.seed)
                if r.size == 0:
                    print(f"{fam} {n} {s:g} 0 (no pair is 'ok' in every draw)", flush=True)
                    continue
                q = [f"{np.median(e):.2f}/{np.percentile(e, p):.2f}"
                     for e, p in zip(eig, (10, 90, 10, 90), strict=True)]
                print(f"{fam} {n} {s:g} {r.size} {np.median(r):.2f} {q[0]} {q[1]} "
                      f"({q[2]} {q[3]})", flush=True)


def main(argv=None):
    use_shared_data()
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--families", default=",".join(FAMILIES))
    p.add_argument("--n-sources", default="20,40")
    p.add_argument("--noise", default="1,5,20", help="position noise in mas")
    p.add_argument("--n-const", type=int, default=10)
    p.add_argument("--n-noise", type=int, default=10)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--jspace", action="store_true",
                   help="check the Jacobian covariance instead (use --n-noise 40 or more)")
    args = p.parse_args(argv)
    if args.jspace:
        _jspace(args)
        return
    print("family n_sources noise_mas n ffr_log [l95, u95] ffr_profile [l95, u95] "
          "ffr_cons [l95, u95] pow25_log pow25_profile pow25_cons powm20_log powm20_profile "
          "powm20_cons")
    for fam in args.families.split(","):
        for n in map(int, args.n_sources.split(",")):
            for s in map(float, args.noise.split(",")):
                r = run_cell(fam, n, s, args.n_const, args.n_noise, args.seed)
                m = r["log_0"].size
                if m == 0:  # every pair untestable
                    print(f"{fam} {n} {s:g} 0 untested", flush=True)
                    continue
                cells = []
                for d in SNRS:
                    k = int(r[f"{d}_0"].sum())
                    lo, hi = _limits(k, m)
                    cells.append(f"{k / m:.4f} [{lo:.4f}, {hi:.4f}]")
                pw = " ".join(f"{r[f'{d}_{a}'].mean():.3f}" for a in ("p25", "m20")
                              for d in SNRS)
                print(f"{fam} {n} {s:g} {m} {' '.join(cells)} {pw}", flush=True)


if __name__ == "__main__":
    main()

"""The pieces of ``lensdual infer``: from analysed constellations to the posterior (private).

:func:`run_inference` takes a validated `~lensdual.config.InferenceConfig`
and calls :mod:`lensdual.inference` once per system:
:class:`~lensdual.inference.SubhaloPopulation` at the smooth lens's
redshifts, :func:`~lensdual.inference.simulate_anomalies`,
:func:`~lensdual.inference.composite_weight` (or the configured weight),
:func:`~lensdual.inference.calibrate_posterior` (by default), then one
:func:`~lensdual.inference.abundance_posterior` over all the systems;
with a grid of WDM half-mode masses (``log_mhm`` a list), one forward model per
system and mass and one :func:`~lensdual.inference.half_mode_posterior`.
What it adds is the preparation the inference page describes for real data:
the pairs placed in the Lenstool model's frame, and the constellation without
measurement noise that the mocks start from (the observed
positions, fluxes that obey duality in the smooth lens). :func:`format_inference_report`
writes the interval with the paper's binomial bound of every system beside it.
"""

import textwrap
import warnings
from typing import NamedTuple

import numpy as np
from astropy import units as u
from astropy.table import QTable

from ._pairs_table import flux_col, flux_err_col, pair_bands, table_sigma_pos
from .inference._population import PYHALO_DEFAULT_SIGMA_SUB

__all__ = ["InferenceRun", "run_inference", "format_inference_report", "table_sigma_pos",
           "table_flux_rel_err", "clean_pairs"]

#: The mass and the zeta of the paper's binomial bound (Sect. 5.4).
PAPER_BOUND_MASS = 1e8 * u.Msun
PAPER_BOUND_ZETA = 3
#: The half-mode mass's marginal in a system's summary of a joint posterior.
_HALF_MODE_KEYS = ("log10_mhm_median", "log10_mhm_interval_68", "log10_mhm_interval_95",
                   "log10_mhm_upper_95")


class InferenceRun(NamedTuple):
    """What :func:`run_inference` returns.

    Parameters
    ----------
    posterior : `~astropy.table.QTable`
        :func:`~lensdual.inference.abundance_posterior` of all the systems
        (:func:`~lensdual.inference.half_mode_posterior` when ``log_mhm`` is
        a grid), with ``meta["systems"]``: one dict per system.
    simulations : list
        One `~lensdual.inference.AnomalySimulation` per system; with a grid
        of half-mode masses, one list per mass (lightest first) of one
        simulation per system, as :func:`~lensdual.inference.half_mode_posterior`
        takes them.
    """

    posterior: QTable
    simulations: list




def table_flux_rel_err(tab):
    """The median relative flux error of a pairs table over its bands and images, or None."""
    ratios = []
    for band in pair_bands(tab):
        for arc in (1, 2):
            f, e = flux_col(arc, band), flux_err_col(arc, band)
            if f in tab.colnames and e in tab.colnames:
                with np.errstate(divide="ignore", invalid="ignore"):
                    ratios.append(np.asarray(u.Quantity(tab[e]).value, dtype=float)
                                  / np.asarray(u.Quantity(tab[f]).value, dtype=float))
    if not ratios:
        return None
    r = np.concatenate(ratios)
    r = r[np.isfinite(r) & (r > 0)]
    return float(np.median(r)) if r.size else None


def _in_lens_frame(spec):
    """``(table, lens, z_lens, z_source, cosmology, description)`` of one system: the
    pairs table with its positions in the smooth lens's frame."""
    if spec.family is not None:
        from .simulation.families import calibration_system

        lens, info = calibration_system(spec.family)
        return (spec.table, lens, info["z_lens"], info["z_source"],
                getattr(lens, "cosmology", None), f"lens family {spec.family}")
    from .parametric import read_lenstool
    from .parametric._frame import frame_reference, in_lenstool_frame, sky_positions

    model = read_lenstool(spec.lenstool)
    sky = sky_positions(spec.table, frame_reference(spec.table, None))
    tab = in_lenstool_frame(spec.table, model, sky)
    return (tab, model, float(model.z_lens), spec.z_source, model.cosmology,
            f"Lenstool model {spec.lenstool.name}")


def clean_pairs(tab, lens, population, flux_rel_err):
    """The constellation without measurement noise that the composite weight starts from.

    The observed positions (in the lens's frame), and in every band fluxes
    that obey duality in the smooth lens: each source's flux is the
    geometric mean of its two images' fluxes corrected by the lens's
    magnifications, ``F = sqrt(f1 |det A1| f2 |det A2|)``, and the images get
    ``F / |det A|``. Pairs without a finite positive flux in every band are
    left out. The flux errors are ``flux_rel_err`` times the fluxes.
    """
    from .inference._forward import as_lens

    lens = as_lens(lens, population)
    xy = [u.Quantity(tab[c], u.arcsec) for c in ("x1", "y1", "x2", "y2")]
    det1 = np.abs(np.linalg.det(np.asarray(lens.jacobian(np.column_stack(xy[:2])), float)))
    det2 = np.abs(np.linalg.det(np.asarray(lens.jacobian(np.column_stack(xy[2:])), float)))
    bands = pair_bands(tab)
    out = QTable()
    out["pair_id"] = (np.asarray(tab["pair_id"], dtype=int) if "pair_id" in tab.colnames
                      else np.arange(1, len(tab) + 1))
    for name, values in zip(("x1", "y1", "x2", "y2"), xy, strict=True):
        out[name] = values
    keep = np.ones(len(tab), dtype=bool)
    for band in bands:
        f1 = u.Quantity(tab[flux_col(1, band)])
        f2 = u.Quantity(tab[flux_col(2, band)]).to(f1.unit)
        with np.errstate(invalid="ignore"):
            source = np.sqrt(f1.value * det1 * f2.value * det2)
        keep &= np.isfinite(source) & (source > 0)
        for arc, det in ((1, det1), (2, det2)):
            flux = source / det * f1.unit
            out[flux_col(arc, band)] = flux
            out[flux_err_col(arc, band)] = flux_rel_err * flux
    out.meta["bands"] = list(bands)
    return out[keep]


def _paper_bound(n_tested, z_lens, z_source, cosmology):
    """The paper's binomial bound (Sect. 5.4) for ``n_tested`` sources without a flag."""
    from .abundance import detection_probability_limit, surface_density_limit

    p_det = detection_probability_limit(n_tested, n_arcs=2, confidence=0.95)
    return surface_density_limit(p_det, PAPER_BOUND_MASS, z_lens=z_lens, z_source=z_source,
                                 zeta=PAPER_BOUND_ZETA, cosmology=cosmology).to(u.kpc**-2)


def _check_kwargs(tab):
    """The settings of the data's duality test, for the composite weight's mocks."""
    duality = tab.meta.get("duality") or {}
    kwargs = {}
    if isinstance(duality.get("method"), str):
        kwargs["method"] = duality["method"]
    for key in ("test", "snr_definition"):
        if isinstance(duality.get(key), str):
            kwargs[key] = duality[key]
    if isinstance(duality.get("snr_threshold"), (int, float)):
        kwargs["snr_threshold"] = float(duality["snr_threshold"])
    return kwargs


def _n_flagged(tab, anomaly):
    """The pairs flagged by the test whose anomalies the posterior reads."""
    joint_table = (tab.meta.get("duality") or {}).get("test") == "joint"
    column = "anomalous_geometric" if anomaly == "geometric" and joint_table else "anomalous"
    return int(np.sum(np.asarray(tab[column], dtype=bool))) if column in tab.colnames else 0


def _step(progress, name):
    from contextlib import nullcontext

    return nullcontext() if progress is None else progress.step(name)


def run_inference(config, *, client=None, progress=None):
    """The posterior on ``sigma_sub`` of the systems of a ``lensdual infer`` configuration.

    With ``log_mhm`` a grid (``config.half_mode``) it is the joint posterior
    on ``sigma_sub`` and the half-mode mass: each system is forward-modelled
    once per half-mode mass, every mass with the system's one seed (the
    realisations of the masses share their random numbers, so the lightest
    mass's simulation is the one a run with that single ``log_mhm`` makes);
    its composite weight is measured once, on the lightest mass's simulation,
    its calibration's mocks are scored on every mass's simulation, and its
    summary in ``meta["systems"]`` is its own joint posterior's marginals.

    Parameters
    ----------
    config : `~lensdual.config.InferenceConfig`
    client : dask.distributed.Client or concurrent.futures.Executor, optional
        Runs each forward model's images as parallel tasks (the result is
        identical to a serial run).
    progress : object with a ``step(name)`` context manager, optional

    Returns
    -------
    `InferenceRun`
    """
    from .inference import (
        SubhaloPopulation,
        abundance_posterior,
        calibrate_posterior,
        composite_weight,
        half_mode_posterior,
        pair_anomalies,
        simulate_anomalies,
    )

    half_mode = config.half_mode
    masses = config.log_mhm if half_mode else (config.log_mhm,)
    tables, sims, weights, infos, calibrations = [], [], [], [], []
    seeds = np.random.SeedSequence(config.seed).generate_state(2 * len(config.systems))
    calibrate = bool(config.calibrate)
    calibration_seeds = np.random.SeedSequence([config.seed, 1]).generate_state(
        len(config.systems))
    for i, spec in enumerate(config.systems):
        tab, lens, z_lens, z_source, cosmology, lens_text = _in_lens_frame(spec)
        pops = [SubhaloPopulation(z_lens, z_source, model=config.model,
                                  log_m_host=config.log_m_host, log_mhm=m,
                                  cosmology=cosmology,
                                  los_normalization=config.los_normalization,
                                  two_halo=config.two_halo) for m in masses]
        with _step(progress, f"forward model {spec.name}"):
            # one seed per system, the same for every half-mode mass: the
            # realisations of the masses share their random numbers
            system_sims = [simulate_anomalies(tab, lens, pop, config.grid,
                                              n_realisations=config.n_realisations,
                                              radius=spec.radius, seed=int(seeds[2 * i]),
                                              client=client) for pop in pops]
        sim = system_sims[0]  # the lightest half-mode mass (masses are sorted)
        sigma_pos = spec.sigma_pos if spec.sigma_pos is not None else table_sigma_pos(tab)
        flux_rel_err = (spec.flux_rel_err if spec.flux_rel_err is not None
                        else table_flux_rel_err(tab))
        # the constellation without noise that the mocks (weight, calibration) start from
        clean = (clean_pairs(tab, lens, pops[0], flux_rel_err)
                 if config.effective_weight == "composite" or calibrate else None)
        if config.effective_weight == "composite":
            with _step(progress, f"composite weight {spec.name}"):
                weight = composite_weight(clean, lens, sim, sigma_pos=sigma_pos,
                                          flux_rel_err=flux_rel_err, n_mocks=config.n_mocks,
                                          seed=int(seeds[2 * i + 1]), anomaly=config.anomaly,
                                          **_check_kwargs(tab))
        else:
            weight = float(config.effective_weight)
        calibration = None
        if calibrate:
            with _step(progress, f"calibration {spec.name}"):
                calibration = calibrate_posterior(
                    clean, lens, system_sims if half_mode else sim, sigma_pos=sigma_pos,
                    flux_rel_err=flux_rel_err,
                    n_mocks=config.n_calibration, seed=int(calibration_seeds[i]),
                    anomaly=config.anomaly, client=client, **_check_kwargs(tab))
        n_tested = len(pair_anomalies(tab, config.anomaly))
        n_flagged = _n_flagged(tab, config.anomaly)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            alone = (half_mode_posterior(tab, system_sims, weights=weight,
                                         anomaly=config.anomaly, calibrations=calibration)
                     if half_mode
                     else abundance_posterior(tab, sim, weights=weight,
                                              anomaly=config.anomaly,
                                              calibrations=calibration)).meta["inference"]
        info = {
            "name": spec.name, "pairs": str(spec.pairs), "lens": lens_text,
            "z_lens": float(z_lens), "z_source": float(z_source), "n_pairs": len(tab),
            "n_tested": n_tested, "n_flagged": n_flagged, "weight": float(weight),
            "weight_source": ("composite" if config.effective_weight == "composite"
                              else "configured" if config.weight is not None else "default"),
            "calibrated": calibrate,
            "sigma_pos": sigma_pos, "flux_rel_err": flux_rel_err,
            "radius": u.Quantity(sim.radius, u.arcsec),
            "median": alone["median"], "interval_68": alone["interval_68"],
            "interval_95": alone["interval_95"],
            "paper_bound": _paper_bound(n_tested, z_lens, z_source, cosmology),
        }
        if half_mode:
            info.update({k: alone[k] for k in _HALF_MODE_KEYS})
        infos.append(info)
        tables.append(tab)
        sims.append(system_sims if half_mode else sim)
        weights.append(weight)
        calibrations.append(calibration)
    with _step(progress, "posterior"):
        if half_mode:
            sims = [list(per_mass) for per_mass in zip(*sims, strict=True)]
            posterior = half_mode_posterior(tables, sims, weights=weights,
                                            anomaly=config.anomaly,
                                            calibrations=calibrations if calibrate else None)
        else:
            posterior = abundance_posterior(tables, sims, weights=weights,
                                            anomaly=config.anomaly,
                                            calibrations=calibrations if calibrate else None)
    posterior.meta["systems"] = infos
    posterior.meta["inference"]["seed"] = int(config.seed)
    posterior.meta["inference"]["anomaly_source"] = config.anomaly_source
    return InferenceRun(posterior, sims)


def _interval(q):
    lo, hi = q.to_value(u.kpc**-2)
    return f"[{lo:.3g}, {hi:.3g}]"


def _log_interval(values):
    lo, hi = values
    return f"[{lo:.2f}, {hi:.2f}]"


def format_inference_report(posterior, *, title="lensdual infer"):
    """The text report of a ``lensdual infer`` posterior.

    Parameters
    ----------
    posterior : `~astropy.table.QTable`
        :func:`run_inference`'s posterior (with ``meta["systems"]``): the
        abundance's, or the joint one with the half-mode mass (a
        ``log10_mhm`` column), whose report gives both marginals.
    title : str, optional

    Returns
    -------
    str
    """
    m = posterior.meta["inference"]
    kpc2 = u.kpc**-2
    half_mode = "log10_mhm" in posterior.colnames
    anomalies = (f"  anomalies: {m['anomaly']}"
                 + {"joint": " (the flux ratio against the joint test's prediction)",
                    "geometric": " (the flux ratio against mu_size)"}.get(m["anomaly"], "")
                 + ("; anomaly = \"auto\": " + ("every table is a joint-test table"
                                                 if m["anomaly"] == "joint" else
                                                 "not every table is a joint-test table")
                    if m.get("anomaly_source") == "auto" else ""))
    summary = (f"  median {m['median'].to_value(kpc2):.3g}   68 % {_interval(m['interval_68'])}"
               f"   95 % {_interval(m['interval_95'])}   95 % upper limit "
               f"{m['upper_95'].to_value(kpc2):.3g}")
    if not half_mode:
        lines = [f"{title}: posterior on the sub-halo abundance sigma_sub (kpc^-2)",
                 f"  {m['n_systems']} system(s), {m['n_pairs']} tested pair(s); prior "
                 f"{m['prior']}; {m['n_realisations']} realisations per abundance",
                 f"  {m['population']}", anomalies, "", summary, ""]
    else:
        pops = m["populations"]
        grid = ", ".join(f"{v:g}" for v in np.unique(np.asarray(posterior["log10_mhm"])))
        lines = [f"{title}: joint posterior on the sub-halo abundance sigma_sub (kpc^-2) and "
                 "the WDM half-mode mass m_hm (log10 Msun)",
                 f"  {m['n_systems']} system(s), {m['n_pairs']} tested pair(s); prior "
                 f"{m['prior']}; {m['n_realisations']} realisations per abundance",
                 f"  half-mode masses log10 m_hm = {grid}; the lightest's population: "
                 f"{pops[0]}", anomalies, "",
                 "  sigma_sub (marginal):",
                 summary,
                 "  half-mode mass, log10 m_hm (marginal):",
                 f"  median {m['log10_mhm_median']:.2f}   68 % "
                 f"{_log_interval(m['log10_mhm_interval_68'])}   95 % "
                 f"{_log_interval(m['log10_mhm_interval_95'])}   95 % upper limit "
                 f"{m['log10_mhm_upper_95']:.2f}", ""]
    header = (f"  {'system':<18s} {'tested':>6s} {'flags':>5s} {'weight':>6s} {'median':>8s} "
              f"{'95 % interval':>20s} {'binomial bound':>14s}")
    if half_mode:
        header += f" {'m_hm 95 % UL':>12s}"
    lines += [header, "  " + "-" * (len(header) - 2)]
    for s in posterior.meta.get("systems", []):
        row = (f"  {s['name']:<18.18s} {s['n_tested']:>6d} {s['n_flagged']:>5d} "
               f"{s['weight']:>6.3f} {s['median'].to_value(kpc2):>8.3g} "
               f"{_interval(s['interval_95']):>20s} "
               f"{s['paper_bound'].to_value(kpc2):>14.3g}")
        if half_mode:
            row += f" {s['log10_mhm_upper_95']:>12.2f}"
        lines.append(row)
    notes = ("The binomial bound is the paper's (Sect. 5.4): the surface density of 1e8 Msun "
             "sub-haloes, each counted within 3 Einstein radii, that no flag among the tested "
             "sources allows at 95 %. It is another quantity than sigma_sub, shown for "
             "orientation, and holds only for a system without flags. pyHalo's default "
             f"sigma_sub is {PYHALO_DEFAULT_SIGMA_SUB} kpc^-2.")
    if m.get("calibrated"):
        cov = m["mock_coverage_uncalibrated"]
        notes += (f" The intervals are calibrated on {m['n_mocks']} mock universes of the "
                  "systems, made as the data: the product of the pairs' likelihoods treats "
                  "their correlated errors as independent, and on these mocks its own 68 % "
                  f"and 95 % intervals of sigma_sub held the truth {100 * cov['68']:.0f} % "
                  f"and {100 * cov['95']:.0f} % of the time")
        if half_mode:
            cov = m["log10_mhm_mock_coverage_uncalibrated"]
            notes += (f", those of the half-mode mass {100 * cov['68']:.0f} % and "
                      f"{100 * cov['95']:.0f} %")
        notes += "."
    else:
        notes += (" The weights correct the product of the pairs' likelihoods for their "
                  "correlated errors; the coverage runs of the docs show that the intervals "
                  "may still be too narrow on some lenses (calibrate = true corrects them).")
    if half_mode:
        notes += (" The half-mode mass's prior is log-uniform on the grid, whose lightest "
                  "masses stand for cold dark matter; where the data cannot tell the masses "
                  "apart its marginal stays flat, and its upper limit is then the prior's "
                  "95 % quantile.")
        if m.get("calibrated"):
            notes += (" Each marginal is calibrated on its own; the joint density is not "
                      "recalibrated.")
        if any(s["weight_source"] == "composite" for s in posterior.meta.get("systems", [])):
            notes += " Each system's composite weight is measured at the lightest mass."
    lines += ["", textwrap.fill(notes, 90)]
    return "\n".join(lines)


def write_inference(run, directory, report_text):
    """posterior.ecsv, posterior.png and report.txt of ``lensdual infer``."""
    from ._outputs import save_figure, write_table
    from .visualization import plot_abundance_posterior, plot_half_mode_posterior

    posterior = run.posterior
    write_table(posterior, directory / "posterior.ecsv")
    if "log10_mhm" in posterior.colnames:
        fig = plot_half_mode_posterior(posterior)
        fig.suptitle(f"{posterior.meta['inference']['n_systems']} system(s), "
                     f"{posterior.meta['inference']['n_pairs']} tested pairs", fontsize=9)
        fig.tight_layout()
        save_figure(fig, directory / "posterior.png", 120)
        (directory / "report.txt").write_text(report_text + "\n")
        return
    systems = posterior.meta.get("systems", [])
    bound = systems[0]["paper_bound"] if len(systems) == 1 else None
    ax = plot_abundance_posterior(posterior, paper_bound=bound,
                                  cdm=PYHALO_DEFAULT_SIGMA_SUB * u.kpc**-2,
                                  label=", ".join(s["name"] for s in systems)[:60])
    ax.set_title(f"{posterior.meta['inference']['n_systems']} system(s), "
                 f"{posterior.meta['inference']['n_pairs']} tested pairs", fontsize=9)
    fig = ax.figure
    fig.tight_layout()
    save_figure(fig, directory / "posterior.png", 120)
    (directory / "report.txt").write_text(report_text + "\n")

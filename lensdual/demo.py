"""The demo scenario of ``lensdual demo``: the paper's SMACS0723 analogue.

:func:`simulate_demo` builds the lens (the analogue's cluster halo, its two
members and one of the paper's sub-haloes 2 mas from the L2 image of one
point source, or a CDM sub-halo population around both arcs) and the true
pairs of a constellation of point sources;
:func:`render_demo` renders the two-band mock images that
:func:`lensdual.pipeline.analyse` takes; :func:`compare_with_truth` compares
the pipeline's pairs table with the injected truth, which only a simulation
can give. From Python, the demo is::

    from lensdual.demo import compare_with_truth, render_demo, simulate_demo, truth_paragraph
    from lensdual.pipeline import analyse, format_report

    system, truth = simulate_demo(seed=0)
    demo = render_demo(system, truth, seed=0)
    analysis = analyse(demo.images, psf=demo.psf, seed=0, null_realisations=1000)
    comparison = compare_with_truth(analysis.result, truth, demo.centre)
    print(format_report(analysis, ["", truth_paragraph(comparison)]))

which is what ``lensdual demo`` prints (with its default options).
"""

import warnings
from dataclasses import dataclass

import numpy as np

__all__ = [
    "DEMO_BANDS",
    "DEMO_CDM_LOG_MASS",
    "DEMO_CDM_MARGIN",
    "DEMO_CDM_THRESHOLD",
    "DEMO_SCENES",
    "DEMO_SUBHALOES",
    "DemoImages",
    "compare_with_truth",
    "render_demo",
    "simulate_demo",
    "truth_paragraph",
]

#: Sub-halo choices of ``lensdual demo --subhalo``.
DEMO_SUBHALOES = ("none", "massive", "small", "overconcentrated", "cdm")

#: log10 mass range [Msun] of the "cdm" population: haloes below 1e8 Msun
#: multiply the run time (every one is a lenstronomy TNFW evaluated on the
#: solver's grid and the rendered pixels) for a small change of the flux ratios.
DEMO_CDM_LOG_MASS = (8.0, 10.0)

#: Margin (arcsec) added to each arc's extent for the radius of its disc of
#: "cdm" sub-haloes.
DEMO_CDM_MARGIN = 0.3

#: A pair counts as perturbed (``subhalo`` True) when ``|ln(mu_true / mu_macro)|``
#: exceeds this: 3 times the error of a flux ratio of two 2% fluxes (the
#: constellation's ``flux_rel_err``), 3 x sqrt(2) x 0.02.
DEMO_CDM_THRESHOLD = 3 * np.sqrt(2) * 0.02

#: The bands of the demo's mock images.
DEMO_BANDS = ("F150W", "F200W")

#: Scene choices of ``lensdual demo --scene``: "point" (every star cluster a
#: point, the default) or "realistic" (star clusters of finite size, their
#: half-light radii drawn log-uniformly in a range, default 1-50 pc, a clumpy
#: host, a cluster member, intracluster light, a diffuse patch under one
#: image and poppy's hexagonal-pupil PSF with diffraction spikes).
DEMO_SCENES = ("point", "realistic")


def _demo_sources(n_sources, rng):
    """A jittered grid of ``n_sources`` sources inside the analogue's fold caustic.

    Table 1's Gaussian of 0.06 arcsec is not resolved at 0.04 arcsec per
    pixel; a grid of 3 columns over the same patch of the source plane keeps
    the images 2-4 PSF widths apart.
    """
    n_rows = -(-n_sources // 3)
    gx = np.array([0.35, 0.65, 0.95])
    gy = np.linspace(6.70, 7.06, max(n_rows, 4))[:n_rows]
    gx, gy = np.meshgrid(gx, gy)
    beta = np.column_stack([gx.ravel(), gy.ravel()])[:n_sources]
    return beta + rng.uniform(-0.02, 0.02, beta.shape)


def _cdm_population(macro, seed):
    """The "cdm" sub-haloes: their TNFW components and their table.

    A `~lensdual.inference.SubhaloPopulation` (CDM, masses in
    :data:`DEMO_CDM_LOG_MASS`, pyHalo's default abundance) drawn, with a
    generator of its own, in one disc per arc: centred on the centroid of
    the arc's images of ``macro``, of radius the largest distance of an image
    from it plus :data:`DEMO_CDM_MARGIN`.
    """
    import astropy.units as u
    from astropy.table import QTable

    from ._lens.component import LensComponent
    from ._pairs_table import arc_xy
    from .inference import SubhaloPopulation
    from .inference._population import PYHALO_DEFAULT_SIGMA_SUB
    from .simulation.scenarios import SMACS0723

    population = SubhaloPopulation(SMACS0723["z_lens"], SMACS0723["z_source"], model="CDM",
                                   log_mlow=DEMO_CDM_LOG_MASS[0],
                                   log_mhigh=DEMO_CDM_LOG_MASS[1])
    rng = np.random.default_rng([seed, 2])
    parts, discs = [], []
    for arc in (1, 2):
        xy = arc_xy(macro, arc)
        centre = xy.mean(axis=0)
        radius = float(np.hypot(*(xy - centre).T).max()) + DEMO_CDM_MARGIN
        halos = population.draw(rng, PYHALO_DEFAULT_SIGMA_SUB, centre, radius)
        halos["arc"] = np.full(halos["x"].size, f"L{arc}")
        parts.append(halos)
        discs.append((float(centre[0]), float(centre[1]), radius))
    table = QTable()
    table["index"] = np.arange(sum(p["x"].size for p in parts))
    table["arc"] = np.concatenate([p["arc"] for p in parts]).astype(str)
    for name in ("x", "y"):
        table[name] = np.concatenate([p[name] for p in parts]) * u.arcsec
    table["mass"] = np.concatenate([p["mass"] for p in parts]) * u.Msun
    for name in ("rs", "alpha_rs", "r_trunc"):
        table[name] = np.concatenate([p[name] for p in parts]) * u.arcsec
    table.meta.update({
        "model": "CDM", "sigma_sub_kpc-2": PYHALO_DEFAULT_SIGMA_SUB,
        "log_m_range": list(DEMO_CDM_LOG_MASS), "log_m_host": population.log_m_host,
        "discs": {f"L{arc}": list(d) for arc, d in zip((1, 2), discs, strict=True)},
        "expected_number": float(population.number_density(
            PYHALO_DEFAULT_SIGMA_SUB / u.kpc**2).to_value(u.arcsec**-2)
            * sum(np.pi * d[2] ** 2 for d in discs)),
    })
    components = [
        LensComponent("TNFW", {"Rs": float(row["rs"].value),
                               "alpha_Rs": float(row["alpha_rs"].value),
                               "r_trunc": float(row["r_trunc"].value),
                               "center_x": float(row["x"].value),
                               "center_y": float(row["y"].value)},
                      f"cdm sub-halo {row['index']}", {"mass": row["mass"]})
        for row in table]
    return components, table


def _nearest_subhaloes(truth, halos):
    """Per pair and image: the nearest sub-halo of ``halos`` (index, mass, distance)."""
    import astropy.units as u

    from ._pairs_table import arc_xy

    hx = np.column_stack([halos["x"].to_value(u.arcsec), halos["y"].to_value(u.arcsec)])
    mass = halos["mass"].to_value(u.Msun)
    for arc in (1, 2):
        xy = arc_xy(truth, arc)
        if len(hx):
            d = np.hypot(xy[:, None, 0] - hx[None, :, 0], xy[:, None, 1] - hx[None, :, 1])
            k = np.argmin(d, axis=1)
            sep, m = d[np.arange(len(xy)), k], mass[k]
        else:
            k, sep, m = np.full(len(xy), -1), np.full(len(xy), np.nan), np.full(len(xy), np.nan)
        truth[f"nearest_subhalo{arc}"] = k
        truth[f"nearest_mass{arc}"] = m * u.Msun
        truth[f"nearest_sep{arc}"] = sep * u.arcsec


def simulate_demo(*, subhalo="overconcentrated", n_sources=12, seed=0, subhalo_source=None):
    """The demo's lens: the SMACS0723 analogue, its members and its sub-halo(es).

    Parameters
    ----------
    subhalo : {"overconcentrated", "massive", "small", "none", "cdm"}
        The paper's sub-haloes (see `lensdual.simulation.SUBHALOES`): 1e8
        Msun with c = 100, 1e9 Msun and 1e8 Msun on the mass-concentration
        relation, put 2 mas from the L2 image of one point source; or
        "cdm": a pyHalo-convention CDM population
        (`~lensdual.inference.SubhaloPopulation` at pyHalo's default
        ``sigma_sub`` = 0.025 kpc^-2, masses in :data:`DEMO_CDM_LOG_MASS`)
        drawn in a disc around each arc, every sub-halo a TNFW component.
        The population's generator is its own (``[seed, 2]``), so the
        sources and fluxes are those of the other choices.
    n_sources : int
        Point sources (3-18), on a jittered grid of 3 columns.
    seed : int
        Seed of the positions and fluxes (and of the "cdm" population).
    subhalo_source : int, optional
        Which source's L2 image gets the sub-halo; default ``n_sources // 3``.
        Not allowed with "cdm".

    Returns
    -------
    system : `~lensdual.simulation.LensSystem`
        The lens: the analogue with its members, plus the sub-halo(es).
    truth : `~astropy.table.QTable`
        The true pairs (``system.constellation``) plus ``mu_macro``, the true
        ``|mu(L1)/mu(L2)|`` without the sub-halo(es) (what ``mu_size``
        measures), and ``subhalo``: True for the perturbed pair, or, with
        "cdm", for the pairs with ``|ln(mu_true / mu_macro)|`` above
        :data:`DEMO_CDM_THRESHOLD`. With "cdm" also the nearest sub-halo
        to each image (``nearest_subhalo1``, ``nearest_mass1``,
        ``nearest_sep1`` and the same for L2) and ``meta["subhaloes"]``,
        the population (a QTable: ``index``, ``arc``, ``x``, ``y``,
        ``mass``, ``rs``, ``alpha_rs``, ``r_trunc``; its meta has the discs
        and the expected number).

    Raises
    ------
    ValueError
        An unknown ``subhalo``, ``n_sources`` or ``subhalo_source`` out
        of range, or ``subhalo_source`` with "cdm".
    """
    import astropy.units as u

    from ._pairs_table import arc_xy
    from .simulation import SUBHALOES, smacs0723_analog, tnfw_halo
    from .simulation.scenarios import SMACS0723

    if subhalo not in DEMO_SUBHALOES:
        raise ValueError(f"subhalo must be one of {DEMO_SUBHALOES}, got {subhalo!r}")
    if not 3 <= int(n_sources) <= 18:
        raise ValueError(f"n_sources must be between 3 and 18, got {n_sources}")
    if subhalo == "cdm" and subhalo_source is not None:
        raise ValueError("subhalo_source places one sub-halo; the 'cdm' population has no "
                         "such choice")
    n_sources = int(n_sources)
    k = n_sources // 3 if subhalo_source is None else int(subhalo_source)
    if not 0 <= k < n_sources:
        raise ValueError(f"subhalo_source must be in [0, {n_sources}), got {subhalo_source}")
    rng = np.random.default_rng(seed)
    base = smacs0723_analog(perturbers=True, seed=seed)
    beta = _demo_sources(n_sources, rng) * u.arcsec
    f0 = 10 ** rng.uniform(np.log10(3.0), 1.0, n_sources)
    flux = {"F150W": f0, "F200W": f0 * 10 ** rng.normal(-0.05, 0.1, n_sources)}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        macro = base.constellation(beta, intrinsic_flux=flux)
    system, halos = base, None
    if subhalo == "cdm":
        components, halos = _cdm_population(macro, seed)
        system = base.add(*components) if components else base
    elif subhalo != "none":
        mass, conc = SUBHALOES[subhalo]
        host = arc_xy(macro, 2)[k]
        sub = tnfw_halo(mass, conc, (host + [0.002, 0.0]) * u.arcsec,
                        z_lens=SMACS0723["z_lens"], z_source=SMACS0723["z_source"],
                        label=f"{subhalo} sub-halo")
        system = base.add(sub)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        truth = system.constellation(beta, intrinsic_flux=flux)
    if halos is None:
        truth["mu_macro"] = macro["mu_true"]
        truth["subhalo"] = np.zeros(n_sources, dtype=bool)
        if subhalo != "none":
            truth["subhalo"][k] = True
    else:
        # a source lost from a fold arc by the population has no macro row to match
        row = {int(s): i for i, s in enumerate(macro["source"])}
        truth = truth[[int(s) in row for s in truth["source"]]]
        truth["mu_macro"] = np.asarray(macro["mu_true"])[[row[int(s)] for s in truth["source"]]]
        shift = np.abs(np.log(np.asarray(truth["mu_true"]) / np.asarray(truth["mu_macro"])))
        truth["subhalo"] = shift > DEMO_CDM_THRESHOLD
        _nearest_subhaloes(truth, halos)
        truth.meta["subhaloes"] = halos
    truth.meta["subhalo"] = subhalo
    return system, truth


@dataclass(frozen=True)
class DemoImages:
    """The demo's mock images, as :func:`~lensdual.pipeline.analyse` takes them.

    Parameters
    ----------
    mocks : `~lensdual.simulation.mock.MockImages`
        The rendered images (output of
        :func:`~lensdual.simulation.render_mock_images`).
    images : dict
        ``{"L1": {band: CCDData}, "L2": {band: CCDData}}``.
    psf : dict of str to `~numpy.ndarray`
        The PSF image of each band.
    centre : `~astropy.coordinates.SkyCoord`
        Sky position of the lens frame's origin (the cluster centre).
    """

    mocks: object
    images: dict
    psf: dict
    centre: object


def render_demo(system, truth, *, seed=0, scene="point", cluster_radii=None, psf=None,
                clumps=None, member=None, icl=None, patch=None):
    """The demo's two-band mock images of both arcs.

    Parameters
    ----------
    system : `~lensdual.simulation.LensSystem`
        The lens (output of :func:`simulate_demo`).
    truth : `~astropy.table.QTable`
        The true pairs (output of :func:`simulate_demo`).
    seed : int
        Seed of the noise (and of the cluster radii of the realistic scene).
    scene : {"point", "realistic"}
        "point": every source is a point, on the lensed Sérsic host, with
        the Gaussian PSF. "realistic": every source is a star cluster of
        finite size (``render_mock_images(r_eff=...)``), its half-light
        radius drawn by :func:`~lensdual.simulation.draw_cluster_radii` in
        ``cluster_radii``, and, unless overridden below, the host has
        faint clumps, a cluster member and an intracluster-light gradient
        sit next to the arcs, a diffuse patch lies under the L2 image of
        pair 0, and the PSF is poppy's hexagonal-pupil PSF with
        diffraction spikes (``psf="poppy"``, needs the ``psf`` extra); the
        noise is the point scene's.
    cluster_radii : tuple of two `~astropy.units.Quantity`, optional
        The range ``(low, high)`` of the realistic scene's radii; default
        `~lensdual.simulation.CLUSTER_RADIUS_RANGE` (1-50 pc).
    psf, clumps, member, icl, patch : optional
        As in :func:`~lensdual.simulation.render_mock_images`; None (the
        default) takes the scene's choice (realistic: ``"poppy"`` and
        True; point: the Gaussian PSF and off).

    Returns
    -------
    `DemoImages`
        The images in :data:`DEMO_BANDS`, their PSFs and the lens centre on
        the sky.
    """
    import astropy.units as u
    from astropy.coordinates import SkyCoord

    from .simulation import CLUSTER_RADIUS_RANGE, draw_cluster_radii, render_mock_images

    if scene not in DEMO_SCENES:
        raise ValueError(f"scene must be one of {DEMO_SCENES}, got {scene!r}")
    r_eff = None
    real = scene == "realistic"
    parts = {"psf": ("poppy" if real else None) if psf is None else psf}
    for name, value in (("clumps", clumps), ("member", member), ("icl", icl),
                        ("patch", patch)):
        parts[name] = real if value is None else value
    if scene == "realistic":
        low, high = CLUSTER_RADIUS_RANGE if cluster_radii is None else cluster_radii
        # a generator of its own: the noise draws are the point scene's
        r_eff = draw_cluster_radii(len(truth), low=low, high=high,
                                   seed=np.random.default_rng([seed, 1]))
    pairs = truth
    if "subhaloes" in truth.meta:
        # the population table stays with the truth: the mocks' pairs meta is written as YAML
        pairs = truth.copy(copy_data=False)
        del pairs.meta["subhaloes"]
    mocks = render_mock_images(system, bands=DEMO_BANDS, pairs=pairs, seed=seed, r_eff=r_eff,
                               **parts)
    images = {arc: dict(mocks.arc(arc)) for arc in ("L1", "L2")}
    psf = {band: np.asarray(mocks[("L1", band)].psf) for band in DEMO_BANDS}
    meta = mocks[("L1", DEMO_BANDS[0])].meta
    centre = SkyCoord(meta["LENSRA"] * u.deg, meta["LENSDEC"] * u.deg)
    return DemoImages(mocks=mocks, images=images, psf=psf, centre=centre)


def compare_with_truth(result, truth, sky_center, *, max_separation=0.1):
    """Match the measured pairs to the simulated ones and compare.

    Parameters
    ----------
    result : `~astropy.table.QTable`
        The duality table (``sky1``, ``sky2`` columns).
    truth : `~astropy.table.QTable`
        Output of :func:`simulate_demo`.
    sky_center : `~astropy.coordinates.SkyCoord`
        Sky position of the lens frame's origin.
    max_separation : float
        Largest L2 separation (arcsec) of a match.

    Returns
    -------
    table : `~astropy.table.QTable`
        One row per measured pair: ``pair_id``, ``source`` (-1 when
        unmatched), ``mu_macro``, ``mu_true``, ``mu_size``, ``size_error``
        (``mu_size / mu_macro - 1``), ``mu_flux``, ``flux_error``
        (``mu_flux / mu_true - 1``), ``subhalo``, ``anomalous``; with the
        "cdm" population also the sub-halo nearest to either image of the
        pair: ``nearest_subhalo`` (its index in ``truth.meta["subhaloes"]``,
        -1 when unmatched), ``nearest_mass``, ``nearest_sep`` (arcsec) and
        ``nearest_arc`` (the image it is nearest to).
        ``meta`` holds the summary: ``n_true``, ``n_matched``,
        ``subhalo_flagged`` (None without a sub-halo), ``false_flags``,
        ``median_abs_size_error``, ``max_abs_size_error``; with "cdm" also
        ``n_subhaloes``, ``n_subhalo_pairs`` (true pairs marked ``subhalo``)
        and ``n_subhalo_flagged`` (those of them flagged).
    """
    import astropy.units as u
    from astropy.table import QTable

    from ._pairs_table import arc_xy, sky_col
    from .simulation import lens_to_sky

    true_sky1 = lens_to_sky(arc_xy(truth, 1) * u.arcsec, sky_center)
    true_sky2 = lens_to_sky(arc_xy(truth, 2) * u.arcsec, sky_center)
    idx2, sep2, _ = result[sky_col(2)].match_to_catalog_sky(true_sky2)
    sep1 = result[sky_col(1)].separation(true_sky1[idx2])
    ok = (sep2.to_value(u.arcsec) < max_separation) & (sep1.to_value(u.arcsec) < max_separation)
    source = np.where(ok, idx2, -1)
    n = len(result)

    def pick(col):
        values = np.asarray(truth[col], dtype=float)
        return np.where(ok, values[idx2], np.nan)

    out = QTable()
    out["pair_id"] = result["pair_id"]
    out["source"] = source
    out["mu_macro"] = pick("mu_macro")
    out["mu_true"] = pick("mu_true")
    out["mu_size"] = np.asarray(result["mu_size"], dtype=float)
    out["size_error"] = out["mu_size"] / out["mu_macro"] - 1
    out["mu_flux"] = np.asarray(result["mu_flux"], dtype=float)
    out["flux_error"] = out["mu_flux"] / out["mu_true"] - 1
    sub = np.asarray(truth["subhalo"], dtype=bool)
    out["subhalo"] = np.where(ok, sub[idx2], False)
    out["anomalous"] = np.asarray(result["anomalous"], dtype=bool)
    cdm = "subhaloes" in truth.meta
    if cdm:
        _nearest_columns(out, truth, ok, idx2)
    errors = np.abs(np.asarray(out["size_error"], dtype=float))
    errors = errors[np.isfinite(errors)]
    distinct = len(set(source[ok].tolist()))
    out.meta.update({
        "n_true": len(truth),
        "n_matched": distinct,
        "subhalo_flagged": (bool((out["anomalous"] & out["subhalo"]).any())
                            if sub.any() else None),
        "false_flags": int(np.sum(out["anomalous"] & ~out["subhalo"])),
        "median_abs_size_error": float(np.median(errors)) if errors.size else np.nan,
        "max_abs_size_error": float(np.max(errors)) if errors.size else np.nan,
        "n_pairs": n,
    })
    if cdm:
        flagged = out["anomalous"] & out["subhalo"]
        out.meta.update({"n_subhaloes": len(truth.meta["subhaloes"]),
                         "n_subhalo_pairs": int(sub.sum()),
                         "n_subhalo_flagged": len(set(source[flagged].tolist()))})
    return out


def _nearest_columns(out, truth, ok, idx2):
    """The nearest sub-halo to either image of each matched pair, into ``out``."""
    import astropy.units as u

    sep = np.column_stack([truth[f"nearest_sep{a}"].to_value(u.arcsec) for a in (1, 2)])
    which = np.argmin(sep, axis=1)
    rows = np.arange(len(truth))
    index = np.column_stack([truth[f"nearest_subhalo{a}"] for a in (1, 2)])[rows, which]
    mass = np.column_stack([truth[f"nearest_mass{a}"].to_value(u.Msun) for a in (1, 2)])
    out["nearest_subhalo"] = np.where(ok, index[idx2], -1)
    out["nearest_mass"] = np.where(ok, mass[rows, which][idx2], np.nan) * u.Msun
    out["nearest_sep"] = np.where(ok, sep[rows, which][idx2], np.nan) * u.arcsec
    out["nearest_arc"] = np.where(ok, np.array(["L1", "L2"])[which][idx2], "")


def truth_paragraph(comparison):
    """The report's paragraph on the comparison with the injected truth.

    Parameters
    ----------
    comparison : `~astropy.table.QTable`
        Output of :func:`compare_with_truth`.

    Returns
    -------
    str
        How many simulated sources were found and paired, how well
        ``mu_size`` matches the smooth lens, whether the sub-haloed pair was
        flagged, and the number of false flags.
    """
    meta = comparison.meta
    text = (f"Compared with the injected truth: {meta['n_matched']} of {meta['n_true']} "
            f"simulated sources were found and paired; mu_size matches the true "
            f"|mu(L1)/mu(L2)| of the smooth lens to {meta['median_abs_size_error']:.1%} "
            f"(median; worst {meta['max_abs_size_error']:.1%}). ")
    flagged = meta["subhalo_flagged"]
    if "n_subhaloes" in meta:
        text += _cdm_sentences(comparison)
    elif flagged is None:
        text += "No sub-halo was injected. "
    else:
        sub = comparison[np.asarray(comparison["subhalo"], dtype=bool)]
        which = f"pair {sub['pair_id'][0]}" if len(sub) else "its pair (not recovered)"
        text += (f"The sub-haloed pair ({which}) was "
                 f"{'flagged' if flagged else 'NOT flagged'}. ")
    text += f"False flags: {meta['false_flags']}."
    return text


def _cdm_sentences(comparison):
    """The "cdm" part of :func:`truth_paragraph`: the marked pairs and the flagged ones,
    each with its nearest sub-halo."""
    meta = comparison.meta
    lo, hi = DEMO_CDM_LOG_MASS
    text = (f"A CDM population of {meta['n_subhaloes']} sub-haloes (1e{lo:g}-1e{hi:g} Msun, "
            f"pyHalo's default abundance) was injected; {meta['n_subhalo_pairs']} true "
            f"pair(s) depart from the smooth lens by more than "
            f"{DEMO_CDM_THRESHOLD:.3f} in |ln(mu_true/mu_macro)|, "
            f"{meta['n_subhalo_flagged']} of them flagged. ")
    rows = comparison[np.asarray(comparison["anomalous"], dtype=bool)]
    if len(rows):
        parts = [f"pair {r['pair_id']} ({'' if r['subhalo'] else 'not perturbed; '}"
                 f"{r['nearest_mass'].to_value('Msun'):.1e} Msun, "
                 f"{r['nearest_sep'].to_value('arcsec'):.3f} arcsec from its {r['nearest_arc']} "
                 f"image)" if r["source"] >= 0 else f"pair {r['pair_id']} (unmatched)"
                 for r in rows]
        text += "Flagged, with the nearest sub-halo: " + "; ".join(parts) + ". "
    return text

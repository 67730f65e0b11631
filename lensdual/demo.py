"""The demo scenario of ``lensdual demo``: the paper's SMACS0723 analogue.

:func:`simulate_demo` builds the lens (the analogue's cluster halo, its two
members and one of the paper's sub-haloes 2 mas from the L2 image of one
point source) and the true pairs of a constellation of point sources;
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
    "DEMO_SCENES",
    "DEMO_SUBHALOES",
    "DemoImages",
    "compare_with_truth",
    "render_demo",
    "simulate_demo",
    "truth_paragraph",
]

#: Sub-halo choices of ``lensdual demo --subhalo``.
DEMO_SUBHALOES = ("none", "massive", "small", "overconcentrated")

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


def simulate_demo(*, subhalo="overconcentrated", n_sources=12, seed=0, subhalo_source=None):
    """The demo's lens: the SMACS0723 analogue, its members and one sub-halo.

    Parameters
    ----------
    subhalo : {"overconcentrated", "massive", "small", "none"}
        The paper's sub-haloes (see `lensdual.simulation.SUBHALOES`): 1e8
        Msun with c = 100, 1e9 Msun and 1e8 Msun on the mass-concentration
        relation. It is put 2 mas from the L2 image of one point source.
    n_sources : int
        Point sources (3-18), on a jittered grid of 3 columns.
    seed : int
        Seed of the positions and fluxes.
    subhalo_source : int, optional
        Which source's L2 image gets the sub-halo; default ``n_sources // 3``.

    Returns
    -------
    system : `~lensdual.simulation.LensSystem`
        The lens: the analogue with its members, plus the sub-halo.
    truth : `~astropy.table.QTable`
        The true pairs (``system.constellation``) plus ``mu_macro``, the true
        ``|mu(L1)/mu(L2)|`` without the sub-halo (what ``mu_size`` measures),
        and ``subhalo`` (True for the perturbed pair).

    Raises
    ------
    ValueError
        An unknown ``subhalo``, or ``n_sources`` or ``subhalo_source`` out
        of range.
    """
    import astropy.units as u

    from ._pairs_table import arc_xy
    from .simulation import SUBHALOES, smacs0723_analog, tnfw_halo
    from .simulation.scenarios import SMACS0723

    if subhalo not in DEMO_SUBHALOES:
        raise ValueError(f"subhalo must be one of {DEMO_SUBHALOES}, got {subhalo!r}")
    if not 3 <= int(n_sources) <= 18:
        raise ValueError(f"n_sources must be between 3 and 18, got {n_sources}")
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
    system = base
    if subhalo != "none":
        mass, conc = SUBHALOES[subhalo]
        host = arc_xy(macro, 2)[k]
        sub = tnfw_halo(mass, conc, (host + [0.002, 0.0]) * u.arcsec,
                        z_lens=SMACS0723["z_lens"], z_source=SMACS0723["z_source"],
                        label=f"{subhalo} sub-halo")
        system = base.add(sub)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        truth = system.constellation(beta, intrinsic_flux=flux)
    truth["mu_macro"] = macro["mu_true"]
    truth["subhalo"] = np.zeros(n_sources, dtype=bool)
    if subhalo != "none":
        truth["subhalo"][k] = True
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
        sit next to the arcs, a diffuse patch lies under the L1 image of
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
    mocks = render_mock_images(system, bands=DEMO_BANDS, pairs=truth, seed=seed, r_eff=r_eff,
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
        (``mu_flux / mu_true - 1``), ``subhalo``, ``anomalous``.
        ``meta`` holds the summary: ``n_true``, ``n_matched``,
        ``subhalo_flagged`` (None without a sub-halo), ``false_flags``,
        ``median_abs_size_error``, ``max_abs_size_error``.
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
    return out


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
    if flagged is None:
        text += "No sub-halo was injected. "
    else:
        sub = comparison[np.asarray(comparison["subhalo"], dtype=bool)]
        which = f"pair {sub['pair_id'][0]}" if len(sub) else "its pair (not recovered)"
        text += (f"The sub-haloed pair ({which}) was "
                 f"{'flagged' if flagged else 'NOT flagged'}. ")
    text += f"False flags: {meta['false_flags']}."
    return text

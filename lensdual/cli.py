"""The ``lensdual`` command line: ``lensdual demo`` and ``lensdual run CONFIG.toml``.

``lensdual demo`` simulates the SMACS0723 analogue of the paper (two cluster
members and one sub-halo on the L2 image of one point source), renders
two-band mock images and analyses them with the real-data pipeline, knowing
nothing of the truth until it compares its results with it at the end.
``lensdual run`` runs the same pipeline on the FITS images named in a TOML
configuration file (see :mod:`lensdual.config`).

The pipeline, for both: point sources are detected on each arc
(:func:`~lensdual.detection.find_point_sources`), measured by PSF photometry
(:func:`~lensdual.photometry.psf_photometry`, for their colours), paired
across the arcs (:func:`~lensdual.pairing.pair_constellations`, automatic or
from a manual list), re-measured as pairs
(:func:`~lensdual.photometry.measure_pairs`) and tested for geometrical
duality (:func:`~lensdual.duality.check_duality`).

Exit codes: 0 success, 1 the analysis failed, 2 bad command line or
configuration (nothing is written then).
"""

import argparse
import os
import shutil
import sys
import tempfile
import time
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = [
    "main",
    "build_parser",
    "simulate_demo",
    "analyse",
    "Analysis",
    "PipelineError",
    "DEMO_SUBHALOES",
]

#: Sub-halo choices of ``lensdual demo --subhalo``.
DEMO_SUBHALOES = ("none", "massive", "small", "overconcentrated")

#: The bands of the demo's mock images.
DEMO_BANDS = ("F150W", "F200W")

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2

_TABLE_COLUMNS_DOC = """\
pairs.ecsv columns (one row per pair; see the "pairs table" page of the docs):
pair_id, id1, id2 (catalogue ids), x1, y1, x2, y2 (arcsec, common tangent-plane
frame, x to the west), sky1, sky2, pos_err1, pos_err2, flux1_<band>,
flux2_<band>, flux_err1_<band>, flux_err2_<band>, jacobian, parity, mu_size,
mu_size_err, mu_size_p16, mu_size_p84, mu_flux_<band>, mu_flux_err_<band>,
mu_flux, mu_flux_err, duality_ratio, duality_ratio_err, snr, snr_paper,
anomalous."""


#: Fewest consistent pairs the automatic pairing accepts (lensdual.pairing).
_MIN_AUTO_PAIRS = 4
#: Why an estimator needs its minimum number of pairs (the error messages).
_MIN_PAIRS_WHY = {
    "adaptive": " (its smallest local fit is a quadratic on a pair and six neighbours, "
                "plus one degree of freedom to test it); with fewer pairs no error bar "
                "of mu_size can be trusted",
}
#: Below this many pairs the paper's estimators fit one nearly global map: their
#: mu_size is almost the same for every pair and their error omits the map's curvature.
_FEW_PAIRS = 7


class PipelineError(RuntimeError):
    """The analysis cannot go on (no detections, too few pairs, ...)."""


# ---------------------------------------------------------------------------
# progress and output helpers
# ---------------------------------------------------------------------------


class _Progress:
    """One tqdm bar over the named steps of a command (silent when quiet)."""

    def __init__(self, steps, *, quiet, desc):
        self.quiet = quiet
        self.bar = None
        if not quiet:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=len(steps), desc=desc, unit="step", file=sys.stderr,
                            leave=False, dynamic_ncols=True,
                            bar_format="{desc}: {n_fmt}/{total_fmt} |{bar}| {postfix} "
                                       "[{elapsed}]")

    @contextmanager
    def step(self, name):
        if self.bar is not None:
            self.bar.set_postfix_str(name)
        yield
        if self.bar is not None:
            self.bar.update(1)

    def close(self):
        if self.bar is not None:
            self.bar.close()


#: The file in an output directory that lists what lensdual wrote there.
_MANIFEST = ".lensdual-outputs"
#: lensdual's own output names, recognised without a manifest (older versions).
_KNOWN_OUTPUTS = ("pairs.ecsv", "catalog_L1.ecsv", "catalog_L2.ecsv", "pairing_map.png",
                  "duality.png", "report.txt", "parametric.ecsv", "parametric.png",
                  "truth_comparison.ecsv", "run.toml", "knot_images.ecsv", "pairs.reg",
                  "sources_L1.reg", "sources_L2.reg", "constellation.png")


def _earlier_outputs(outdir):
    """Files of ``outdir`` that an earlier lensdual run wrote (relative paths)."""
    manifest = outdir / _MANIFEST
    if manifest.is_file():
        names = [line.strip() for line in manifest.read_text().splitlines() if line.strip()]
        return [n for n in names if (outdir / n).is_file() and ".." not in Path(n).parts]
    found = [n for n in _KNOWN_OUTPUTS if (outdir / n).is_file()]
    found += sorted(p.name for p in outdir.glob("knots_*.ecsv"))
    found += sorted(p.name for p in outdir.glob("knots_*.png"))
    return found


def check_output_directory(outdir):
    """Fail early, before any analysis, when ``outdir`` cannot be written.

    Raises
    ------
    OSError
        ``outdir`` (or a parent) is not a directory, cannot be created, or
        is not writable; the message names the path.
    """
    outdir = Path(outdir)
    if outdir.exists() and not outdir.is_dir():
        raise NotADirectoryError(f"output directory {outdir} exists and is not a directory")
    parent = outdir.resolve().parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        probe = Path(tempfile.mkdtemp(prefix=f".{outdir.name}.probe-", dir=parent))
        probe.rmdir()
    except OSError as err:
        raise OSError(f"cannot write the output directory {outdir}: {err.strerror or err} "
                      f"(in {parent}); choose another --outdir") from None
    if outdir.exists() and not os.access(outdir, os.W_OK | os.X_OK):
        raise PermissionError(f"output directory {outdir} is not writable; choose another "
                              "--outdir")


@contextmanager
def _atomic_directory(outdir, removed=None):
    """Write into a temporary sibling of ``outdir``; move the files there on success.

    Nothing is left in ``outdir`` when the block raises: files already there
    are only replaced once every output has been written. Then lensdual's own
    outputs of an earlier run that this run did not write again are removed
    (their names are appended to ``removed``), so that no stale file sits
    next to new ones; other files are never touched.
    """
    outdir = Path(outdir)
    parent = outdir.resolve().parent
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{outdir.name}.partial-", dir=parent))
    try:
        yield tmp
        outdir.mkdir(parents=True, exist_ok=True)
        written = sorted(str(p.relative_to(tmp)) for p in tmp.rglob("*") if p.is_file())
        stale = [n for n in _earlier_outputs(outdir) if n not in written]
        for path in sorted(tmp.rglob("*")):
            target = outdir / path.relative_to(tmp)
            if path.is_dir():
                target.mkdir(parents=True, exist_ok=True)
            else:
                os.replace(path, target)
        for name in stale:
            (outdir / name).unlink(missing_ok=True)
        if removed is not None:
            removed.extend(stale)
        (outdir / _MANIFEST).write_text("\n".join(written) + "\n")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _fmt(value, spec=".3f"):
    value = float(value)
    return "nan" if not np.isfinite(value) else format(value, spec)


# ---------------------------------------------------------------------------
# the pipeline shared by demo and run
# ---------------------------------------------------------------------------


@dataclass
class Analysis:
    """What :func:`analyse` found.

    Attributes
    ----------
    catalogs : dict of str to `~astropy.table.QTable`
        The point-source catalogue of each arc (``"L1"``, ``"L2"``) with its
        PSF fluxes per band.
    pairs : `~astropy.table.QTable`
        The pairing (output of :func:`~lensdual.pairing.pair_constellations`).
    result : `~astropy.table.QTable`
        The duality table (output of :func:`~lensdual.duality.check_duality`
        on the PSF-measured pairs).
    sigma_pos : `~astropy.units.Quantity`
        The positional errors used for the bootstrap.
    warnings : list of str
        The distinct warnings raised on the way.
    """

    catalogs: dict
    pairs: object
    result: object
    sigma_pos: object
    warnings: list = field(default_factory=list)


def _catalogue(images, psf, catalog=None, oversampling=None):
    """Detections (or the given catalogue) of one arc, with PSF fluxes per band."""
    from astropy.table import QTable

    from .detection import find_point_sources
    from .photometry import psf_photometry

    if catalog is None:
        found = find_point_sources(images)
        if found is None:
            return None
        catalog = {"id": found["id"], "sky": found["sky_centroid"]}
    out = QTable({"id": catalog["id"], "sky": catalog["sky"]})
    for k, (band, image) in enumerate(images.items()):
        xy = np.column_stack(image.wcs.world_to_pixel(out["sky"]))
        if k == 0:  # pixel position on the first band, for reference
            out["x_pix"], out["y_pix"] = xy[:, 0], xy[:, 1]
        phot = psf_photometry(image, xy, psf=psf.get(band), warn=False,
                              oversampling=(oversampling or {}).get(band))
        out[f"flux_{band}"] = phot["flux"]
        out[f"flux_err_{band}"] = phot["flux_err"]
    return out


def analyse(images, *, psf=None, estimator="adaptive", sigma_pos="auto", n_bootstrap=1000,
            snr_threshold=3.0, seed=0, catalogs=None, manual_pairs=None, progress=None,
            null_realisations=0, oversampling=None):
    """Run the pipeline from images of two arcs to the duality table.

    Parameters
    ----------
    images : dict
        ``{"L1": {band: CCDData}, "L2": {band: CCDData}}``; every image needs
        a celestial WCS; the same bands on both arcs.
    psf : dict of str to PSF, optional
        Per band, what :func:`~lensdual.photometry.psf_photometry` takes as
        ``psf`` (a FWHM, a PSF image, or None to fit a Gaussian FWHM).
    estimator : {"adaptive", "quad2", "quad", "2v"}
        Size-magnification estimator (default ``"adaptive"``).
    sigma_pos : "auto" or `~astropy.units.Quantity`
        Positional error of the bootstrap. ``"auto"`` (default): each point
        source's own error from the PSF fits (``pos_err1``, ``pos_err2``).
    n_bootstrap, snr_threshold, seed
        As in :func:`~lensdual.duality.check_duality`; ``seed`` also seeds
        the pairing.
    catalogs : dict of str to `~astropy.table.Table`, optional
        Point-source lists of the arcs (``id`` and ``sky`` columns) used
        instead of detection.
    manual_pairs : `~astropy.table.Table`, optional
        ``id1``, ``id2`` of the pairs (catalogue ids): manual pairing.
    progress : `_Progress`, optional
    oversampling : dict of str to int, optional
        Per band, the oversampling of its PSF image (see
        :func:`~lensdual.photometry.psf_photometry`).
    null_realisations : int
        With ``estimator="adaptive"`` and a value >= 100, also run
        :func:`~lensdual.duality.null_calibration` with that many
        realisations: its summary goes to ``meta['duality']['null_calibration']``
        and its per-pair empirical p-values to column ``p_value_empirical``.

    Returns
    -------
    `Analysis`

    Raises
    ------
    PipelineError
        No point sources on an arc, or too few pairs.
    """
    import astropy.units as u

    from .duality import check_duality
    from .estimators import METHODS
    from .pairing import pair_constellations
    from .photometry import measure_pairs

    psf = dict(psf or {})
    progress = progress or _Progress([], quiet=True, desc="")
    if estimator not in METHODS:
        raise ValueError(f"estimator must be one of {list(METHODS)}, got {estimator!r}")
    n_min = max(METHODS[estimator], _MIN_AUTO_PAIRS if manual_pairs is None else 3)
    bands = list(images["L1"])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cats = {}
        for arc in ("L1", "L2"):
            with progress.step(f"detect + photometry {arc}"):
                given = None if catalogs is None else catalogs[arc]
                cats[arc] = _catalogue(images[arc], psf, given, oversampling)
            n_found = 0 if cats[arc] is None else len(cats[arc])
            if n_found < n_min:
                hints = [str(w.message) for w in caught
                         if w.category.__name__ == "NoDetectionsWarning"]
                raise PipelineError(
                    f"only {n_found} point source(s) found on arc {arc}: the {estimator} "
                    f"estimator needs at least {n_min} pairs{_MIN_PAIRS_WHY.get(estimator, '')}"
                    + (f". The detection said: {hints[-1]}" if hints else ""))
        to_pair = cats if manual_pairs is not None else {
            arc: _significant(cat, bands, arc) for arc, cat in cats.items()}
        with progress.step("pair"):
            try:
                pairs = pair_constellations(
                    to_pair["L1"], to_pair["L2"], ids=manual_pairs, position_columns="sky",
                    flux_columns=[f"flux_{b}" for b in bands], seed=seed)
            except ValueError as err:
                raise PipelineError(f"pairing failed: {err}") from err
            if len(pairs) < n_min:
                raise PipelineError(
                    f"only {len(pairs)} pair(s) found: the {estimator} estimator needs at "
                    f"least {n_min}{_MIN_PAIRS_WHY.get(estimator, '')}")
        with progress.step("PSF photometry of the pairs"):
            measured = measure_pairs(images["L1"], images["L2"], pairs, psf=psf, bands=bands,
                                     oversampling=oversampling or None)
        doubt = pairing_doubts(pairs)
        _drop_non_positive(measured, bands, doubt)
        if "measured" in measured.colnames:
            for k in np.flatnonzero(~np.asarray(measured["measured"], dtype=bool)):
                if not doubt[k]:
                    doubt[k] = f"not measured ({measured['photometry_note'][k]})"
        measured["doubt"] = np.array([str(d) for d in doubt], dtype=str)
        step = (f"mu_size ({estimator})" if estimator == "adaptive"
                else f"mu_size ({estimator}, {n_bootstrap} bootstraps)")
        with progress.step(step):
            if isinstance(sigma_pos, str):
                sigma = np.vstack([measured["pos_err1"].to_value(u.arcsec),
                                   measured["pos_err2"].to_value(u.arcsec)]) * u.arcsec
            else:
                sigma = sigma_pos
            result = check_duality(measured, estimator, sigma_pos=sigma,
                                   n_bootstrap=n_bootstrap, snr_threshold=snr_threshold,
                                   seed=seed)
        if null_realisations and estimator == "adaptive":
            with progress.step(f"null calibration ({null_realisations} realisations)"):
                _add_null_calibration(result, measured, sigma, null_realisations,
                                      snr_threshold, seed)
    messages = list(dict.fromkeys(f"{w.category.__name__}: {w.message}" for w in caught))
    return Analysis(cats, pairs, result, sigma, messages)


# ---------------------------------------------------------------------------
# the demo's simulation and truth
# ---------------------------------------------------------------------------


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
    truth : `~astropy.table.QTable`
        The true pairs (``system.constellation``) plus ``mu_macro``, the true
        ``|mu(L1)/mu(L2)|`` without the sub-halo (what ``mu_size`` measures),
        and ``subhalo`` (True for the perturbed pair).
    """
    import astropy.units as u

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
        host = np.array([macro["x2"][k].to_value(u.arcsec), macro["y2"][k].to_value(u.arcsec)])
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

    from .simulation import lens_to_sky

    true_sky1 = lens_to_sky(np.column_stack([truth["x1"].to_value(u.arcsec),
                                             truth["y1"].to_value(u.arcsec)]) * u.arcsec,
                            sky_center)
    true_sky2 = lens_to_sky(np.column_stack([truth["x2"].to_value(u.arcsec),
                                             truth["y2"].to_value(u.arcsec)]) * u.arcsec,
                            sky_center)
    idx2, sep2, _ = result["sky2"].match_to_catalog_sky(true_sky2)
    sep1 = result["sky1"].separation(true_sky1[idx2])
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


# ---------------------------------------------------------------------------
# reporting
# ---------------------------------------------------------------------------


def format_pairs_table(result):
    """The per-pair table as printed by the commands (a str)."""
    bands = list(result.meta.get("bands", []))
    head = ["pair", "id1", "id2"] + [f"mu_flux {b}" for b in bands] + [
        "mu_size", "+-", "ratio", "SNR", "flag"]
    rows = []
    for row in result:
        cells = [str(row["pair_id"]), str(row["id1"]), str(row["id2"])]
        cells += [_fmt(row[f"mu_flux_{b}"]) for b in bands]
        cells += [_fmt(row["mu_size"]), _fmt(row["mu_size_err"]),
                  _fmt(row["duality_ratio"]), _fmt(row["snr"], ".1f"),
                  _flag(row)]
        rows.append(cells)
    widths = [max(len(h), *(len(r[k]) for r in rows)) if rows else len(h)
              for k, h in enumerate(head)]
    lines = ["  ".join(h.rjust(w) for h, w in zip(head, widths, strict=True))]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(c.rjust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
    return "\n".join(lines)


#: A pair is a doubtful pairing when another partner fits about as well (confidence
#: below this) ...
_DOUBT_CONFIDENCE = 1e-3
#: ... or when its offset from the arc-to-arc map exceeds this many robust rms.
_DOUBT_RESIDUAL = 6.0


def pairing_doubts(pairs):
    """Why each pair of a pairing is doubtful ("" when it is not; an object array).

    A mis-pair must never look like a sub-halo. The pairing
    (:func:`~lensdual.pairing.pair_constellations`) gives every pair its
    offset from the fitted arc-to-arc map (``residual``) and the probability
    that its partner is the right one (``confidence``). A pair is doubtful
    when its confidence is below 1e-3 (another partner fits as well: e.g.
    two swapped ids, or a spurious detection next to the true image), or
    when its residual exceeds 6 times the robust rms of the pairing (it is
    off the map: e.g. a manual pair on blank sky). Colours are checked by
    :func:`~lensdual.duality.check_duality` (``chromatic_alpha``).
    """
    n = len(pairs)
    doubt = np.array([""] * n, dtype=object)
    rms = float(pairs.meta.get("rms_robust", np.nan)) if hasattr(pairs, "meta") else np.nan
    if "residual" in pairs.colnames and np.isfinite(rms) and rms > 0:
        col = pairs["residual"]
        res = np.asarray(col.to_value("arcsec") if getattr(col, "unit", None) else col,
                         dtype=float)
        with np.errstate(invalid="ignore"):
            off = res > _DOUBT_RESIDUAL * rms
        for k in np.flatnonzero(off):
            doubt[k] = (f"off the arc-to-arc map (residual {1e3 * res[k]:.0f} mas, "
                        f"{res[k] / rms:.0f} x the pairing's robust rms)")
    if "confidence" in pairs.colnames:
        conf = np.asarray(pairs["confidence"], dtype=float)
        with np.errstate(invalid="ignore"):
            low = (doubt == "") & (conf < _DOUBT_CONFIDENCE)
        for k in np.flatnonzero(low):
            doubt[k] = (f"ambiguous pairing (confidence {conf[k]:.1g}: another partner fits "
                        "about as well)")
    return doubt


#: Automatic pairing uses only candidates whose PSF flux is at least this many sigma
#: in some band: blank-sky detections would otherwise drown the constellation's
#: triangles (and become spurious pairs).
_MIN_CANDIDATE_SNR = 3.0


def _significant(cat, bands, arc):
    """The rows of a catalogue significant in at least one band (warning for the rest)."""
    from .exceptions import LensdualWarning

    snr = np.zeros(len(cat))
    for band in bands:
        f = np.asarray(getattr(cat[f"flux_{band}"], "value", cat[f"flux_{band}"]), float)
        e = np.asarray(getattr(cat[f"flux_err_{band}"], "value", cat[f"flux_err_{band}"]),
                       float)
        with np.errstate(invalid="ignore", divide="ignore"):
            snr = np.fmax(snr, np.where(np.isfinite(f / e), f / e, 0.0))
    keep = snr >= _MIN_CANDIDATE_SNR
    if not keep.all():
        warnings.warn(f"arc {arc}: {int((~keep).sum())} candidate(s) below {_MIN_CANDIDATE_SNR:g} "
                      f"sigma in every band left out of the automatic pairing (ids "
                      f"{np.asarray(cat['id'])[~keep].tolist()[:20]})", LensdualWarning,
                      stacklevel=2)
    return cat[keep]


def _drop_non_positive(measured, bands, doubt):
    """A non-positive PSF flux (blank sky, a spurious candidate) is no flux: NaN in that
    band, and the pair is doubtful (in place)."""
    for band in bands:
        for arc in ("1", "2"):
            flux = measured[f"flux{arc}_{band}"]
            values = np.asarray(getattr(flux, "value", flux), dtype=float)
            with np.errstate(invalid="ignore"):
                bad = np.isfinite(values) & (values <= 0)
            for k in np.flatnonzero(bad):
                if not doubt[k]:
                    doubt[k] = (f"non-positive flux on L{arc} in {band} ({values[k]:.3g}): "
                                "blank sky or a spurious detection")
            if bad.any():
                for col in (f"flux{arc}_{band}", f"flux_err{arc}_{band}"):
                    measured[col][bad] = np.nan * getattr(measured[col], "unit", 1)


def _flag(row):
    """The flag column of the printed table: ANOMALOUS, ok, or why a pair is untested."""
    if row["anomalous"]:
        return "ANOMALOUS"
    if "tested" in row.colnames and not row["tested"]:
        return f"untested ({_untested_reason(row)})"
    return "ok"


def _untested_reason(row):
    if "doubt" in row.colnames and str(row["doubt"]):
        return "doubtful pairing"
    status = str(row["mu_size_status"]) if "mu_size_status" in row.colnames else ""
    if not np.isfinite(float(row["mu_size"])):
        return "no mu_size"
    if status in ("untestable", "failed"):
        return f"mu_size {status}"
    if not np.isfinite(float(row["mu_flux"])):
        return "no flux ratio"
    return "no SNR"


def verdict(result, sigma_pos):
    """One paragraph on which pairs break duality, and how strongly (a str)."""
    import astropy.units as u

    meta = result.meta.get("duality", {})
    bands = list(result.meta.get("bands", []))
    threshold = meta.get("snr_threshold", 3.0)
    sig = np.asarray(u.Quantity(sigma_pos, u.arcsec).to_value(u.mas))
    if sig.size > 1:
        sig_text = f"positional errors from the PSF fits (median {np.median(sig):.1f} mas)"
    else:
        sig_text = f"sigma_pos = {float(sig):.1f} mas"
    method = meta.get("method", "?")
    errors = ("analytic errors that include the estimator's truncation error"
              if method == "adaptive" else
              f"{meta.get('n_bootstrap', '?')} bootstrap realisations (position noise only)")
    text = (f"{len(result)} point-source pairs were measured on arcs L1 and L2 in "
            f"{len(bands)} band{'s' if len(bands) != 1 else ''} ({', '.join(bands)}). "
            f"Size magnifications from the {method} estimator with "
            f"{sig_text} and {errors}; a pair is "
            f"anomalous when |ln(mu_flux/mu_size)| exceeds {threshold:g} times its error. ")
    if "tested" in result.colnames:
        n_tested = int(np.count_nonzero(result["tested"]))
        untested = result[~np.asarray(result["tested"], dtype=bool)]
    else:
        n_tested, untested = meta.get("n_tested", len(result)), result[:0]
    if len(untested):
        reasons = {}
        for row in untested:
            reasons.setdefault(_untested_reason(row), []).append(str(row["pair_id"]))
        listed = "; ".join(f"{why}: pair{'s' if len(ids) > 1 else ''} {', '.join(ids)}"
                           for why, ids in reasons.items())
        text += (f"{len(untested)} pair(s) could not be tested and are NOT passes "
                 f"(column 'tested'; {listed}). ")
        doubtful = untested[[bool(str(d)) for d in untested["doubt"]]] if "doubt" in \
            untested.colnames else untested[:0]
        if len(doubtful):
            text += ("Doubtful pairings are left out of the size magnification of the other "
                     "pairs and never counted as anomalies: "
                     + "; ".join(f"pair {r['pair_id']} ({r['id1']}, {r['id2']}): {r['doubt']}"
                                 for r in doubtful) + ". ")
    if method != "adaptive" and len(result) < _FEW_PAIRS:
        text += (f"WARNING: only {len(result)} pairs: the {method} estimator then fits one "
                 "nearly global map (mu_size almost the same for every pair) and its error "
                 "holds the position noise only, not the map's curvature, so its flags are "
                 f"not calibrated. Use at least {_FEW_PAIRS} pairs and the adaptive "
                 "estimator. ")
    bad = result[np.asarray(result["anomalous"], dtype=bool)]
    text += _calibration_sentence(len(bad), n_tested, meta)
    if len(bad) == 0:
        if n_tested == 0:
            text += ("No pair could be tested, so the data say nothing about geometrical "
                     "duality here: no conclusion on sub-haloes.")
        elif len(untested):
            text += (f"No pair breaks geometrical duality among the {n_tested} tested: no "
                     "sub-halo is detected near them; the untested pairs are no evidence "
                     "either way.")
        else:
            text += ("No pair breaks geometrical duality: flux and size magnifications agree "
                     "everywhere, so no sub-halo is detected near these point sources.")
        return text
    parts = []
    for row in bad:
        ratio = float(row["duality_ratio"])
        if ratio > 1:
            how = f"its L1 image is {ratio - 1:.0%} brighter, relative to L2,"
        else:
            how = f"its L2 image is {1 / ratio - 1:.0%} brighter, relative to L1,"
        parts.append(f"pair {row['pair_id']} (mu_flux = {_fmt(row['mu_flux'])} +- "
                     f"{_fmt(row['mu_flux_err'])}, mu_size = {_fmt(row['mu_size'])} +- "
                     f"{_fmt(row['mu_size_err'])}, ratio {_fmt(ratio, '.2f')}, SNR "
                     f"{_fmt(row['snr'], '.1f')}: {how} than the geometry allows)")
    n_bad = len(bad)
    text += (f"{n_bad} pair{'s break' if n_bad > 1 else ' breaks'} geometrical duality: "
             + "; ".join(parts) + ". A flux anomaly at fixed geometry is the signature of "
             "unseen sub-structure (a sub-halo) near one of the two images. "
             f"The other {n_tested - n_bad} tested pairs agree with duality.")
    return text


def _add_null_calibration(result, measured, sigma, n_realisations, snr_threshold, seed):
    """Run the null calibration and record it in ``result`` (in place)."""
    from .duality import null_calibration

    null = null_calibration(measured, sigma_pos=sigma, n_realisations=n_realisations,
                            snr_threshold=snr_threshold, seed=seed)
    result["p_value_empirical"] = null["p_value_empirical"]
    keys = ("n_realisations", "false_alarm_rate", "nominal_false_alarm_rate",
            "expected_false_flags", "p_any_false_flag", "family_wise_p_empirical",
            "map_degree", "map_chi2_dof")
    result.meta["duality"]["null_calibration"] = {k: null.meta[k] for k in keys}


def _percent(p):
    """A probability as a percentage, '< 0.01 %' below 1e-4."""
    if not np.isfinite(p):
        return "undefined"
    return "< 0.01%" if p < 1e-4 else f"{100 * p:.2g}%"


def _calibration_sentence(n_bad, n_tested, meta):
    """'k pairs of N flagged; the chance of at least one such flag without any sub-halo...'."""
    if "p_any_false_flag" not in meta:
        return ""
    text = (f"{n_bad} pair{'s' if n_bad != 1 else ''} of {n_tested} tested flagged "
            f"(expected without any sub-halo: {meta['expected_false_flags']:.2g}); ")
    if n_bad:
        text += (f"the chance of at least one flag as strong without any sub-halo is "
                 f"{_percent(meta['family_wise_p'])}. ")
    else:
        text += (f"the chance of at least one flag without any sub-halo is "
                 f"{_percent(meta['p_any_false_flag'])}. ")
    null = meta.get("null_calibration")
    if null:
        floor = (" (the smallest p-value this many realisations can give)"
                 if null["family_wise_p_empirical"] <= 1.5 / null["n_realisations"] else "")
        text += (f"On {null['n_realisations']} simulated clean constellations like this one "
                 f"(null calibration) {null['false_alarm_rate']:.2%} of pairs were flagged "
                 f"(nominal {null['nominal_false_alarm_rate']:.2%}), "
                 f"{null['p_any_false_flag']:.1%} of them had at least one flag, and a flag "
                 f"as strong as the strongest here occurred in "
                 f"{_percent(null['family_wise_p_empirical'])}{floor}. ")
    return text


def _truth_paragraph(comparison):
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


# ---------------------------------------------------------------------------
# writing
# ---------------------------------------------------------------------------


def _write_table(table, path):
    table.write(path, format="ascii.ecsv", overwrite=True)


def _write_figures(analysis, directory, *, title, images=None):
    import matplotlib

    if matplotlib.get_backend().lower() not in ("agg", "pdf", "svg", "cairo"):
        matplotlib.use("agg")
    import matplotlib.pyplot as plt

    from .visualization import plot_duality, plot_pairing_map

    fig, ax = plt.subplots(figsize=(5.5, 5.5))
    plot_pairing_map(analysis.pairs, analysis.catalogs["L1"], analysis.catalogs["L2"], ax=ax)
    ax.set_title(f"{title}: pairing (L1 rotated onto L2)", fontsize="medium")
    fig.tight_layout()
    fig.savefig(directory / "pairing_map.png", dpi=120)
    plt.close(fig)
    if images is not None:
        from .visualization import plot_arc_images

        fig = plot_arc_images(images, analysis.result)
        fig.suptitle(f"{title}: the pairs on both arcs", fontsize="medium")
        fig.savefig(directory / "constellation.png", dpi=110)
        plt.close(fig)
    fig, ax = plt.subplots(figsize=(5.5, 5.5))
    plot_duality(analysis.result, ax=ax, title=f"{title}: duality test")
    fig.tight_layout()
    fig.savefig(directory / "duality.png", dpi=120)
    plt.close(fig)


def _write_regions(analysis, directory):
    """DS9 region files: the pairs (numbered, with lines) and each arc's detections."""
    from .visualization import ds9_regions

    regions = ds9_regions(analysis.result, analysis.catalogs)
    regions["pairs"].write(str(directory / "pairs.reg"), format="ds9", overwrite=True)
    for arc in ("L1", "L2"):
        if arc in regions:
            regions[arc].write(str(directory / f"sources_{arc}.reg"), format="ds9",
                               overwrite=True)


def _write_analysis(analysis, directory, report_text, *, title, images=None):
    for arc, cat in analysis.catalogs.items():
        _write_table(cat, directory / f"catalog_{arc}.ecsv")
    _write_table(analysis.result, directory / "pairs.ecsv")
    _write_regions(analysis, directory)
    _write_figures(analysis, directory, title=title, images=images)
    (directory / "report.txt").write_text(report_text + "\n")


def _report(analysis, extra=()):
    parts = [format_pairs_table(analysis.result), "", verdict(analysis.result,
                                                             analysis.sigma_pos)]
    parts += [p for p in extra if p]
    if analysis.warnings:
        parts += ["", "Warnings raised on the way:"] + [f"  {w}" for w in analysis.warnings]
    return "\n".join(parts)


#: Settings of the demo's parametric fit (tests make it cheaper): the halo
#: centre is held on the cluster centre (the BCG, known to the observer).
_DEMO_FIT = {"sigma_pos": 0.01, "n_starts": 4, "fix_centre": True}


def _fit_kwargs(fix_centre=False, n_starts=None, max_nfev=None):
    kwargs = {}
    if fix_centre:
        kwargs["fixed_params"] = {0: {"center_x": 0.0, "center_y": 0.0}}
    if n_starts is not None:
        kwargs["n_starts"] = n_starts
    if max_nfev is not None:
        kwargs["max_nfev"] = max_nfev
    return kwargs


def _parametric_outputs(analysis, directory, *, lenstool=None, fit=False, model=None,
                        z_lens=None, z_source=None, sigma_pos=0.01, centre=None, seed=0,
                        fit_kwargs=None):
    """The parametric comparison: table and figure into ``directory``."""
    import astropy.units as u
    import matplotlib.pyplot as plt

    from .parametric import parametric_comparison

    kwargs = {"lenstool": lenstool, "fit": fit, "z_lens": z_lens, "z_source": z_source,
              "seed": seed, "centre": centre,
              "fit_kwargs": {"sigma_pos": u.Quantity(sigma_pos, u.arcsec),
                             **(fit_kwargs or {})}}
    if model is not None:
        kwargs["model"] = tuple(model)
    table, fig = parametric_comparison(analysis.result, **kwargs)
    _write_table(table, directory / "parametric.ecsv")
    fig.savefig(directory / "parametric.png", dpi=120)
    plt.close(fig)
    return table


def _parametric_paragraph(table):
    meta = table.meta.get("parametric", {})
    parts = []
    if meta.get("fit_model"):
        parts.append(f"A parametric lenstronomy fit ({' + '.join(meta['fit_model'])}, "
                     f"chi2 = {meta.get('chi2', float('nan')):.1f} for {meta.get('dof')} "
                     f"degrees of freedom at sigma_pos = {meta.get('sigma_pos', 0) * 1e3:.0f} "
                     "mas)")
    if meta.get("lenstool"):
        parts.append(f"the Lenstool model {Path(meta['lenstool']).name}")
    text = " and ".join(parts) + " predicted |mu(L1)/mu(L2)| for every pair"
    text = text[0].upper() + text[1:]
    model_label = "the fitted model" if meta.get("fit_model") else "the Lenstool model"
    for col, label in (("anomalous_model", model_label),
                       ("anomalous_lenstool", "the Lenstool model")):
        if col in table.colnames:
            ids = [str(i) for i in table["pair_id"][np.asarray(table[col], dtype=bool)]]
            text += (f"; against {label}, {len(ids)} pair(s) break duality"
                     + (f" ({', '.join(ids)})" if ids else ""))
    return text + " (parametric.ecsv, parametric.png)."


# ---------------------------------------------------------------------------
# the demo's config for ``lensdual run``
# ---------------------------------------------------------------------------


def _write_run_inputs(mocks, directory, *, estimator, n_bootstrap, snr_threshold, seed,
                      centre, parametric=False, null_realisations=0):
    """FITS images, error maps and PSFs of the mocks, and a config that reads them."""
    from astropy.io import fits

    data = directory / "data"
    data.mkdir(parents=True, exist_ok=True)
    config = {
        "output": {"outdir": "run-output"},
        "analysis": {"estimator": estimator, "sigma_pos": "auto",
                     "n_bootstrap": int(n_bootstrap), "snr_threshold": float(snr_threshold),
                     "seed": int(seed), "null_realisations": int(null_realisations)},
        "bands": {}, "arcs": {"L1": {}, "L2": {}},
    }
    for (arc, band), image in mocks.items():
        header = image.wcs.to_header()
        header["BUNIT"] = image.unit.to_string()
        header["BAND"] = band
        fits.writeto(data / f"{arc}_{band}_sci.fits", np.asarray(image.data, dtype=float),
                     header, overwrite=True)
        fits.writeto(data / f"{arc}_{band}_err.fits",
                     np.asarray(image.uncertainty.array, dtype=float), header, overwrite=True)
        config["arcs"][arc][band] = {"image": f"data/{arc}_{band}_sci.fits",
                                     "error": f"data/{arc}_{band}_err.fits"}
        if band not in config["bands"]:
            fits.writeto(data / f"psf_{band}.fits", np.asarray(image.psf, dtype=float),
                         overwrite=True)
            config["bands"][band] = {"psf": f"data/psf_{band}.fits"}
    if parametric:
        config["parametric"] = {"fit": True, "z_lens": 0.39, "z_source": 2.2,
                                "sigma_pos": f"{_DEMO_FIT['sigma_pos']} arcsec",
                                "centre": f"{centre.ra.deg:.7f} {centre.dec.deg:.7f}",
                                "fix_centre": bool(_DEMO_FIT.get("fix_centre", False))}
    header = ("lensdual run configuration written by `lensdual demo --write-config`:\n"
              "the demo's mock images as FITS files (science, error map, PSF),\n"
              "analysed with the demo's settings. Run it with\n"
              "    lensdual run run.toml\n"
              "Relative paths are relative to this file.")
    return config, header


# ---------------------------------------------------------------------------
# commands
# ---------------------------------------------------------------------------


def _show_progress(args):
    """Progress bars only on a terminal (stderr) or with --progress; never with --quiet."""
    if args.quiet:
        return False
    return bool(getattr(args, "progress", False)) or sys.stderr.isatty()


def _print(args, text=""):
    if not args.quiet:
        print(text, flush=True)


#: Errors that end a command with a message and exit code 1 (ConfigError, raised
#: by load_images for a cut-out off the image, is a ValueError).
_FAILURES = (PipelineError, ValueError, OSError)


def _finish(args, command, progress, start, *, report=None, outdir=None, error=None,
            removed=()):
    """Close the progress bar; print the report (or the error); the exit code."""
    progress.close()
    if error is not None:
        kind = "" if isinstance(error, PipelineError) else f"{type(error).__name__}: "
        print(f"lensdual {command}: {kind}{error}", file=sys.stderr)
        return EXIT_FAILED
    _print(args, report)
    _print(args, f"\nOutputs in {outdir} ({time.perf_counter() - start:.1f} s).")
    if removed:
        _print(args, f"Removed {len(removed)} output(s) of an earlier lensdual run there that "
                     f"this run did not write: {', '.join(removed)}.")
    return EXIT_OK


def _cmd_demo(args):
    import astropy.units as u
    from astropy.coordinates import SkyCoord

    from .simulation import render_mock_images, write_mock_images

    start = time.perf_counter()
    try:
        check_output_directory(args.outdir)
    except OSError as err:
        print(f"lensdual demo: {err}", file=sys.stderr)
        return EXIT_FAILED
    removed = []
    steps = ["simulate", "render", "detect L1", "detect L2", "pair", "photometry", "mu_size",
             "write"] + (["parametric"] if args.parametric else [])
    progress = _Progress(steps, quiet=not _show_progress(args), desc="lensdual demo")
    try:
        with progress.step("simulate the lens"):
            system, truth = simulate_demo(subhalo=args.subhalo, n_sources=args.n_sources,
                                          seed=args.seed)
        with progress.step("render mock images"):
            mocks = render_mock_images(system, bands=DEMO_BANDS, pairs=truth, seed=args.seed)
        images = {arc: dict(mocks.arc(arc)) for arc in ("L1", "L2")}
        psf = {band: np.asarray(mocks[("L1", band)].psf) for band in DEMO_BANDS}
        # the null calibration is the adaptive estimator's
        null_realisations = args.null_realisations if args.estimator == "adaptive" else 0
        analysis = analyse(images, psf=psf, estimator=args.estimator, sigma_pos="auto",
                           n_bootstrap=args.n_bootstrap, snr_threshold=args.snr_threshold,
                           seed=args.seed, progress=progress,
                           null_realisations=null_realisations)
        meta = mocks[("L1", DEMO_BANDS[0])].meta
        centre = SkyCoord(meta["LENSRA"] * u.deg, meta["LENSDEC"] * u.deg)
        comparison = compare_with_truth(analysis.result, truth, centre)
        report = _report(analysis, ["", _truth_paragraph(comparison)])
        with _atomic_directory(args.outdir, removed) as tmp:
            with progress.step("write outputs"):
                write_mock_images(mocks, tmp / "images")
                _write_table(comparison, tmp / "truth_comparison.ecsv")
                if args.write_config:
                    config, header = _write_run_inputs(
                        mocks, tmp, estimator=args.estimator, n_bootstrap=args.n_bootstrap,
                        snr_threshold=args.snr_threshold, seed=args.seed, centre=centre,
                        parametric=args.parametric, null_realisations=null_realisations)
                    from .config import write_config

                    write_config(tmp / "run.toml", config, header=header)
            if args.parametric:
                with progress.step("parametric fit"):
                    settings = dict(_DEMO_FIT)
                    sigma = settings.pop("sigma_pos")
                    fit_kwargs = _fit_kwargs(**settings)
                    table = _parametric_outputs(analysis, tmp, fit=True, z_lens=0.39,
                                                z_source=2.2, sigma_pos=sigma, centre=centre,
                                                seed=args.seed, fit_kwargs=fit_kwargs)
                report += "\n\n" + _parametric_paragraph(table)
            _write_analysis(analysis, tmp, report, title="lensdual demo", images=images)
    except _FAILURES as err:
        return _finish(args, "demo", progress, start, error=err)
    return _finish(args, "demo", progress, start, report=report, outdir=args.outdir,
                   removed=removed)


def _cmd_run(args):
    from astropy.table import QTable

    from .config import ConfigError, band_oversampling, band_psfs, load_config, load_images

    start = time.perf_counter()
    try:
        config = load_config(args.config, outdir=args.outdir)
    except ConfigError as err:
        print(f"lensdual run: {err}", file=sys.stderr)
        return EXIT_USAGE
    try:
        check_output_directory(config.outdir)
    except OSError as err:
        print(f"lensdual run: {err}", file=sys.stderr)
        return EXIT_FAILED
    if config.knots is not None:
        return _run_knots(args, config, start)
    removed = []
    par = config.parametric
    steps = ["read", "detect L1", "detect L2", "pair", "photometry", "mu_size", "write"]
    if par is not None:
        steps.append("parametric")
    progress = _Progress(steps, quiet=not _show_progress(args), desc="lensdual run")
    try:
        with progress.step("read images"), warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            images = load_images(config)
            psf = band_psfs(config)
            oversampling = band_oversampling(config)
            catalogs = None
            if config.catalogs is not None:
                catalogs = {arc: _read_catalog(path) for arc, path in config.catalogs.items()}
            manual = None
            if config.pairing_method == "manual":
                manual = QTable.read(config.pairs_file, format="ascii.ecsv")
        analysis = analyse(images, psf=psf, estimator=config.estimator,
                           sigma_pos=config.sigma_pos, n_bootstrap=config.n_bootstrap,
                           snr_threshold=config.snr_threshold, seed=config.seed,
                           catalogs=catalogs, manual_pairs=manual, progress=progress,
                           null_realisations=config.null_realisations,
                           oversampling=oversampling)
        read_warnings = [f"{w.category.__name__}: {w.message}" for w in caught]
        analysis.warnings[:0] = list(dict.fromkeys(read_warnings))
        for text in read_warnings:
            print(f"lensdual run: warning: {text}", file=sys.stderr)
        extra = []
        with _atomic_directory(config.outdir, removed) as tmp:
            if par is not None and (par.lenstool is not None or par.fit):
                with progress.step("parametric comparison"):
                    table = _parametric_outputs(
                        analysis, tmp, lenstool=par.lenstool, fit=par.fit, model=par.model,
                        z_lens=par.z_lens, z_source=par.z_source, sigma_pos=par.sigma_pos,
                        centre=par.centre, seed=config.seed,
                        fit_kwargs=_fit_kwargs(par.fix_centre))
                extra = ["", _parametric_paragraph(table)]
            report = _report(analysis, extra)
            with progress.step("write outputs"):
                _write_analysis(analysis, tmp, report, title=Path(args.config).stem,
                                images=images)
    except _FAILURES as err:
        return _finish(args, "run", progress, start, error=err)
    return _finish(args, "run", progress, start, report=report, outdir=config.outdir,
                   removed=removed)


def _run_knots(args, config, start):
    """``lensdual run`` on a ``[knots]`` configuration: a catalogue, no images."""
    from .pipeline import analyse_knots, knot_report

    spec = config.knots
    progress = _Progress(["analyse", "write"], quiet=not _show_progress(args),
                         desc="lensdual run")
    try:
        with progress.step("knot constellation"):
            macro = spec.centres if spec.centres is not None else list(spec.macro_images)
            mapping = None
            if spec.mapping is not None:
                from astropy.table import Table

                mapping = Table.read(spec.mapping, format="ascii.ecsv")
            sigma = spec.sigma_pos
            analysis = analyse_knots(spec.catalogue, macro, knots=spec.knot_filter(),
                                     assign=spec.assign, mapping=mapping,
                                     models=list(spec.models), z_source=spec.z_source,
                                     sigma_pos=sigma, method=config.estimator,
                                     snr_threshold=config.snr_threshold)
        report = knot_report(analysis)
        removed = []
        with _atomic_directory(config.outdir, removed) as tmp, progress.step("write outputs"):
            _write_table(analysis.knot_pairs.images, tmp / "knot_images.ecsv")
            for (m1, m2), table in analysis.tables.items():
                stem = f"knots_{m1}_{m2}"
                _write_table(table, tmp / f"{stem}.ecsv")
                if table.meta.get("models"):
                    _write_knot_figure(table, tmp / f"{stem}.png")
            (tmp / "report.txt").write_text(report + "\n")
    except _FAILURES as err:
        return _finish(args, "run", progress, start, error=err)
    return _finish(args, "run", progress, start, report=report, outdir=config.outdir,
                   removed=removed)


def _write_knot_figure(table, path):
    import matplotlib

    if matplotlib.get_backend().lower() not in ("agg", "pdf", "svg", "cairo"):
        matplotlib.use("agg")
    import matplotlib.pyplot as plt

    from .parametric import plot_size_vs_model

    fig, ax = plt.subplots(figsize=(5.5, 5.5))
    plot_size_vs_model(table, ax=ax)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _read_catalog(path):
    import astropy.units as u
    from astropy.coordinates import SkyCoord
    from astropy.table import QTable

    cat = QTable.read(path, format="ascii.ecsv")
    if "sky" not in cat.colnames:
        cat["sky"] = SkyCoord(u.Quantity(cat["ra"], u.deg), u.Quantity(cat["dec"], u.deg))
    return cat


def _int_range(lo, hi=None):
    """An argparse type: an integer in [lo, hi]."""

    def convert(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < lo or (hi is not None and value > hi):
            bound = f">= {lo}" if hi is None else f"between {lo} and {hi}"
            raise argparse.ArgumentTypeError(f"expected an integer {bound}, got {value}")
        return value

    return convert


def _positive_float(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {value}")
    return value


def _config_schema():
    """The annotated example configuration of :mod:`lensdual.config`'s docstring."""
    import textwrap

    from . import config

    doc = config.__doc__
    start = doc.index("::\n\n") + 4
    end = doc.index("\n\n", doc.index("z_source", start))
    knots = doc.index("::\n\n", doc.index("[knots]")) + 4
    knots_end = doc.index("\n\n", doc.index("sigma_pos", knots))
    return (textwrap.dedent(doc[start:end]) + "\n\n# or, for a catalogue-only run (no images):\n"
            + textwrap.dedent(doc[knots:knots_end]))


def build_parser():
    """The `argparse.ArgumentParser` of the ``lensdual`` command."""
    from . import __version__
    from .estimators import METHODS

    parser = argparse.ArgumentParser(
        prog="lensdual",
        description="Find dark sub-haloes with geometrical duality: compare the flux ratio "
                    "of each point-source pair of two lens arcs with its model-independent "
                    "size magnification.",
        epilog="Run 'lensdual demo' first: it needs no files and takes about 10 s "
               "(25 s the first time).")
    parser.add_argument("--version", action="version", version=f"lensdual {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    demo = sub.add_parser(
        "demo", help="simulate the paper's SMACS0723 analogue and run the whole pipeline",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        description="Simulate the SMACS0723 analogue of the paper (main halo, two cluster "
                    "members, one sub-halo 2 mas from the L2 image of one point source), "
                    "render two-band JWST-like mock images (F150W, F200W), then detect, pair "
                    "automatically, measure by PSF photometry, estimate the size "
                    "magnification with bootstrap errors and test duality, without using "
                    "the truth; at the end, compare with the injected truth. Writes the "
                    "images (FITS), catalogues and the pairs table (ECSV), the pairing map "
                    "and the duality figure (PNG) and a report to OUTDIR.",
        epilog=_TABLE_COLUMNS_DOC)
    demo.add_argument("--outdir", default="lensdual-demo", type=Path,
                      help="output directory (created; files in it are replaced)")
    demo.add_argument("--subhalo", choices=DEMO_SUBHALOES, default="overconcentrated",
                      help="the injected sub-halo: 1e8 Msun with c = 100 "
                           "(overconcentrated), 1e9 Msun (massive) or 1e8 Msun (small) on the "
                           "mass-concentration relation, or none")
    demo.add_argument("--seed", type=_int_range(0), default=0,
                      help="seed of the simulation, noise, pairing and bootstrap")
    demo.add_argument("--n-sources", type=_int_range(3, 18), default=12,
                      help="point sources in the constellation (3-18)")
    demo.add_argument("--n-bootstrap", type=_int_range(10), default=1000,
                      help="bootstrap realisations of the positional noise")
    demo.add_argument("--estimator", choices=sorted(METHODS), default="adaptive",
                      help="size-magnification estimator (adaptive: local fits chosen by the "
                           "data, errors that include the estimator's own; quad2, quad, 2v: "
                           "bootstrap errors of the position noise only)")
    demo.add_argument("--null-realisations", type=_int_range(0), default=200,
                      help="simulated clean constellations for the null calibration of the "
                           "adaptive test (0: off; otherwise >= 100)")
    demo.add_argument("--snr-threshold", type=_positive_float, default=3.0,
                      help="a pair is anomalous above this duality SNR")
    demo.add_argument("--write-config", action="store_true",
                      help="also write the mock images as FITS files with error maps and "
                           "PSFs under OUTDIR/data and a matching OUTDIR/run.toml for "
                           "'lensdual run'")
    demo.add_argument("--parametric", action="store_true",
                      help="also fit a parametric lenstronomy model (NFW_ELLIPSE_CSE + SHEAR) "
                           "to the pairs and compare its magnification ratios "
                           "(parametric.ecsv, parametric.png)")
    demo.add_argument("--progress", action="store_true",
                     help="show progress bars even when stderr is not a terminal (by "
                          "default they appear on a terminal only, so logs stay clean)")
    demo.add_argument("--quiet", "-q", action="store_true",
                      help="print nothing (no progress bars, no table); errors still go to "
                           "stderr")
    demo.set_defaults(func=_cmd_demo)

    run = sub.add_parser(
        "run", help="run the pipeline on real images named in a TOML configuration file",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Run the pipeline on the FITS images of a TOML configuration file "
                    "(images, error or weight maps, PSFs per band and arc; optional "
                    "cut-outs, catalogues, manual pairs, parametric models). The whole "
                    "file is checked before any work starts: every problem is listed in "
                    "one message and the exit code is 2. Outputs (catalogue_L1/L2.ecsv, "
                    "pairs.ecsv, pairing_map.png, duality.png, report.txt) appear in the "
                    "output directory only when all of them have been written. "
                    "'lensdual demo --write-config' writes an example.",
        epilog=_TABLE_COLUMNS_DOC + "\n\nThe configuration file (relative paths are "
               "relative to it; angles are strings with units):\n\n" + _config_schema())
    run.add_argument("config", type=Path, help="the TOML configuration file")
    run.add_argument("--outdir", type=Path, default=None,
                     help="output directory (overrides [output] outdir of the file)")
    run.add_argument("--progress", action="store_true",
                     help="show progress bars even when stderr is not a terminal (by "
                          "default they appear on a terminal only, so logs stay clean)")
    run.add_argument("--quiet", "-q", action="store_true",
                     help="print nothing (no progress bars, no table); errors still go to "
                          "stderr")
    run.set_defaults(func=_cmd_run)
    return parser


def main(argv=None):
    """Entry point of the ``lensdual`` command; returns the exit code."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, usage errors
        return int(exc.code or 0)
    return args.func(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""The analyses a Python user runs without the command line.

:func:`analyse` is the image pipeline of ``lensdual demo`` and ``lensdual run``:
point sources are detected on each arc
(:func:`~lensdual.detection.find_point_sources`), measured by PSF photometry
(:func:`~lensdual.photometry.psf_photometry`, for their colours), paired
across the arcs (:func:`~lensdual.pairing.pair_constellations`, automatic or
from a manual list), re-measured as pairs
(:func:`~lensdual.photometry.measure_pairs`) and tested for geometrical
duality (:func:`~lensdual.duality.check_duality`). It returns an `Analysis`;
:func:`format_pairs_table`, :func:`verdict` and :func:`format_report` turn it
into the text the commands print (they live in ``lensdual._report``, with
:func:`knot_report`). Writing files is left to the caller (the
command line writes ECSV tables, figures and DS9 regions).

:func:`analyse_knots` is the catalogue-only analysis of ``lensdual run`` with a
``[knots]`` table: the knots of a multiply-imaged galaxy in a published
multiple-image catalogue are paired across its macro-images, their size
magnification is measured with position errors taken from the constellation
itself, and compared with the magnification ratios of lens models.
"""

import warnings
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from astropy import units as u

from . import _precompile as precompile
from ._diffuse_light import doubt_diffuse_light
from ._doubts import add_doubt, no_doubts
from ._lost_pairs import with_lost_pairs
from ._pairs_table import (
    ARCS,
    POS_ERR_COLUMNS,
    arc_xy,
    check_distinct_arcs,
    flux_col,
    flux_err_col,
)
from ._report import format_pairs_table, format_report, knot_report, verdict
from ._report import parametric_paragraph as parametric_paragraph  # re-exported
from ._validation import as_angle_scalar, as_real
from .duality import (
    DEFAULT_SNR_DEFINITION,
    DEFAULT_SNR_THRESHOLD,
    DEFAULT_TEST,
    LOG_SNR_DEFINITIONS,
    check_test_settings,
)
from .estimators import DEFAULT_METHOD, DEFAULT_N_BOOTSTRAP, estimate_sigma_pos
from .exceptions import PipelineError

# The seed of analyse (and of lensdual run's [analysis] seed): runs repeat.
DEFAULT_SEED = 0

__all__ = [
    "Analysis",
    "PipelineError",
    "analyse",
    "format_pairs_table",
    "format_report",
    "pairing_doubts",
    "verdict",
    "KnotAnalysis",
    "analyse_knots",
    "knot_report",
]

#: Fewest consistent pairs the automatic pairing accepts (lensdual.pairing).
_MIN_AUTO_PAIRS = 4
#: Why an estimator needs its minimum number of pairs (the error messages).
_MIN_PAIRS_WHY = {
    "adaptive": " (its smallest local fit is a quadratic on a pair and six neighbours, "
                "plus one degree of freedom to test it); with fewer pairs no error bar "
                "of mu_size can be trusted",
}


class _NoProgress:
    """The progress of :func:`analyse` when nobody watches: every step is silent."""

    @staticmethod
    def step(name):
        return nullcontext()


# ---------------------------------------------------------------------------
# the image pipeline shared by lensdual demo and lensdual run
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Analysis:
    """What :func:`analyse` found.

    Parameters
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


def _check_catalogue_footprint(catalog, images, arc):
    """A given catalogue must put sources on its arc's images; say why where none is."""
    band, image = next(iter(images.items()))
    sky = catalog["sky"]
    ny, nx = image.shape

    def on_image(coords):
        x, y = image.wcs.world_to_pixel(coords)
        return (np.isfinite(x) & np.isfinite(y) & (x >= -0.5) & (x <= nx - 0.5)
                & (y >= -0.5) & (y <= ny - 0.5))

    if len(sky) == 0 or on_image(sky).any():
        return
    centre = image.wcs.pixel_to_world((nx - 1) / 2, (ny - 1) / 2)
    nearest = float(centre.separation(sky).deg.min())
    text = (f"none of the {len(sky)} positions of the arc {arc} catalogue falls on its {band} "
            f"image (the nearest is {nearest:.3g} deg from the image centre)")
    hours = sky.__class__(sky.ra * 15.0, sky.dec, frame=sky.frame)
    if (sky.ra.deg <= 24.0).all() and on_image(hours).any():
        text += (": its RA values look like hours, read as degrees; give the 'ra' column "
                 "the unit hourangle, or convert it to degrees")
    raise PipelineError(text)


def analyse(images, *, psf=None, estimator=DEFAULT_METHOD, sigma_pos="auto",
            n_bootstrap=DEFAULT_N_BOOTSTRAP, snr_threshold=DEFAULT_SNR_THRESHOLD,
            seed=DEFAULT_SEED,
            catalogs=None, manual_pairs=None, progress=None, null_realisations=0,
            oversampling=None, test=DEFAULT_TEST, max_magnification=None,
            source_model="point", snr_definition=DEFAULT_SNR_DEFINITION):
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
    progress : object, optional
        Reports the steps: its ``step(name)`` is a context manager entered
        around each step (the command line's progress bar). Default: silent.
    null_realisations : int
        With ``estimator="adaptive"`` and a value >= 100, also run
        :func:`~lensdual.duality.null_calibration` with that many
        realisations: its summary goes to ``meta['duality']['null_calibration']``
        and its per-pair empirical p-values to column ``p_value_empirical``.
    oversampling : dict of str to int, optional
        Per band, the oversampling of its PSF image (see
        :func:`~lensdual.photometry.psf_photometry`).
    max_magnification : float, optional
        The automatic pairing's bound on the map, see
        :func:`~lensdual.pairing.pair_constellations` (default its default).
    test : {"auto", "geometric", "joint"}
        The duality test of :func:`~lensdual.duality.check_duality` and of
        the null calibration (default ``"auto"``: the joint test where it
        applies, see :func:`~lensdual.duality.resolve_test`, else the
        geometric one); ``"joint"`` needs ``estimator="adaptive"``.
    snr_definition : {"auto", "log", "conservative"}
        The SNR of :func:`~lensdual.duality.check_duality` and of the null
        calibration (default ``"auto"``: ``"conservative"`` with the adaptive
        estimator, else ``"log"``); ``"conservative"`` needs
        ``estimator="adaptive"``.
    source_model : {"point", "resolved"}
        The photometry of the pairs (:func:`~lensdual.photometry.measure_pairs`):
        ``"point"`` (default) fits the PSF; ``"resolved"`` fits the PSF
        convolved with an elliptical Gaussian of free size, for slightly
        resolved sources (see :ref:`photometry-resolved`).

    Returns
    -------
    `Analysis`
        The catalogues, the pairing, the duality table, the positional
        errors used and the warnings raised on the way.

    Raises
    ------
    PipelineError
        No point sources on an arc, or too few pairs.
    """
    from .duality import check_duality
    from .estimators import METHODS
    from .pairing import DEFAULT_MAX_MAGNIFICATION, pair_constellations
    from .photometry import measure_pairs

    psf = dict(psf or {})
    progress = progress or _NoProgress()
    if estimator not in METHODS:
        raise ValueError(f"estimator must be one of {list(METHODS)}, got {estimator!r}")
    if snr_definition not in ("auto",) + LOG_SNR_DEFINITIONS:
        raise ValueError(f"snr_definition must be one of {['auto', *LOG_SNR_DEFINITIONS]}, got "
                         f"{snr_definition!r}")
    n_min = max(METHODS[estimator], _MIN_AUTO_PAIRS if manual_pairs is None else 3)
    bands = list(images["L1"])
    # checked here, before the images are read; check_duality resolves "auto" again
    # (and records why it ran the geometric test)
    _, resolved_snr, _ = check_test_settings(test, snr_definition, estimator, bands)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cats = {}
        for arc in ("L1", "L2"):
            with progress.step(f"detect + photometry {arc}"):
                given = None if catalogs is None else catalogs[arc]
                if given is not None:
                    _check_catalogue_footprint(given, images[arc], arc)
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
                    flux_columns=[f"flux_{b}" for b in bands], seed=seed,
                    max_magnification=(DEFAULT_MAX_MAGNIFICATION if max_magnification is None
                                       else max_magnification))
            except ValueError as err:
                raise PipelineError(f"pairing failed: {err}") from err
            if len(pairs) < n_min:
                raise PipelineError(
                    f"only {len(pairs)} pair(s) found: the {estimator} estimator needs at "
                    f"least {n_min}{_MIN_PAIRS_WHY.get(estimator, '')}")
            check_distinct_arcs(pairs)
            to_measure, lost = (pairs, {}) if manual_pairs is not None else \
                with_lost_pairs(pairs, to_pair, images)
        with progress.step("PSF photometry of the pairs"):
            measured = measure_pairs(images["L1"], images["L2"], to_measure, psf=psf,
                                     bands=bands, oversampling=oversampling or None,
                                     source_model=source_model)
        doubt = pairing_doubts(to_measure)
        for row, reason in lost.items():
            add_doubt(doubt, np.arange(len(doubt)) == row, reason)
        _drop_non_positive(measured, bands, doubt)
        _doubt_faint(measured, bands, doubt)
        if "measured" in measured.colnames:
            add_doubt(doubt, ~np.asarray(measured["measured"], dtype=bool),
                      lambda k: f"not measured ({measured['photometry_note'][k]})")
        if isinstance(sigma_pos, str):
            _doubt_missing_position_errors(measured, doubt)
        diffuse = doubt_diffuse_light(measured, bands, doubt)
        measured["doubt"] = np.array([str(d) for d in doubt], dtype=str)
        step = (f"mu_size ({estimator})" if estimator == "adaptive"
                else f"mu_size ({estimator}, {n_bootstrap} bootstraps)")
        with progress.step(step):
            if precompile.running() and resolved_snr == "conservative":
                # the profile SNR's kernels, compiled here while the second process
                # compiles the rest (it leaves them out)
                precompile.compile_profile_kernels()
            precompile.wait()  # the kernels a second process compiled (see lensdual._precompile)
            if isinstance(sigma_pos, str):
                sigma = np.vstack([measured[c].to_value(u.arcsec)
                                   for c in POS_ERR_COLUMNS]) * u.arcsec
            else:
                sigma = sigma_pos
            result = check_duality(measured, estimator, sigma_pos=sigma,
                                   n_bootstrap=n_bootstrap, snr_threshold=snr_threshold,
                                   seed=seed, test=test, snr_definition=snr_definition)
            result.meta["diffuse_light"] = diffuse
        if null_realisations and estimator == "adaptive":
            with progress.step(f"null calibration ({null_realisations} realisations)"):
                _add_null_calibration(result, measured, sigma, null_realisations,
                                      snr_threshold, seed, test, snr_definition)
    messages = list(dict.fromkeys(f"{w.category.__name__}: {w.message}" for w in caught))
    return Analysis(cats, pairs, result, sigma, messages)

# ---------------------------------------------------------------------------
# pairing doubts and flags
# ---------------------------------------------------------------------------


def _doubt_missing_position_errors(measured, doubt):
    """A pair whose PSF fits gave no position error (``sigma_pos = "auto"``) is
    doubtful: its errors are unknown, so it is left out of the estimate and
    reported untested with the reason."""
    for arc, name in zip(ARCS, POS_ERR_COLUMNS, strict=True):
        err = measured[name].to_value(u.arcsec)
        add_doubt(doubt, ~(np.isfinite(err) & (err > 0)),
                  f"no position error from the PSF fit on arc L{arc} (is there a point source?)")


#: A pair is a doubtful pairing when another partner fits about as well (confidence
#: below this) ...
_DOUBT_CONFIDENCE = 1e-3
#: ... or when its offset from the arc-to-arc map exceeds this many robust rms.
_DOUBT_RESIDUAL = 6.0


def pairing_doubts(pairs):
    """Why each pair of a pairing is doubtful.

    A mis-pair must never look like a sub-halo. The pairing
    (:func:`~lensdual.pairing.pair_constellations`) gives every pair its
    offset from the fitted arc-to-arc map (``residual``) and the probability
    that its partner is the right one (``confidence``). A pair is doubtful
    when its confidence is below 1e-3 (another partner fits as well: e.g.
    two swapped ids, or a spurious detection next to the true image), or
    when its residual exceeds 6 times the robust rms of the pairing (it is
    off the map: e.g. a manual pair on blank sky). Colours are checked by
    :func:`~lensdual.duality.check_duality` (``chromatic_alpha``).

    Parameters
    ----------
    pairs : `~astropy.table.QTable`
        A pairing (:func:`~lensdual.pairing.pair_constellations`); without
        its ``residual`` and ``confidence`` columns no pair is doubtful.

    Returns
    -------
    doubt : `~numpy.ndarray` of object
        Per pair, why it is doubtful, or ``""`` when it is not.
    """
    doubt = no_doubts(len(pairs))
    rms = float(pairs.meta.get("rms_robust", np.nan)) if hasattr(pairs, "meta") else np.nan
    if "residual" in pairs.colnames and np.isfinite(rms) and rms > 0:
        col = pairs["residual"]
        res = np.asarray(col.to_value("arcsec") if getattr(col, "unit", None) else col,
                         dtype=float)
        with np.errstate(invalid="ignore"):
            off = res > _DOUBT_RESIDUAL * rms
        add_doubt(doubt, off, lambda k: (f"off the arc-to-arc map (residual "
                                         f"{1e3 * res[k]:.0f} mas, {res[k] / rms:.0f} x the "
                                         "pairing's robust rms)"))
    if "confidence" in pairs.colnames:
        conf = np.asarray(pairs["confidence"], dtype=float)
        with np.errstate(invalid="ignore"):
            low = conf < _DOUBT_CONFIDENCE
        add_doubt(doubt, low, lambda k: (f"ambiguous pairing (confidence {conf[k]:.1g}: "
                                         "another partner fits about as well)"))
    return doubt


#: A point source is a candidate whose PSF flux is at least this many sigma in some
#: band. Automatic pairing uses only those (blank-sky detections would otherwise drown
#: the constellation's triangles and become spurious pairs), and a measured pair whose
#: image on an arc is fainter in every band is doubtful (a manual candidate on blank sky).
_MIN_CANDIDATE_SNR = 3.0


def _best_snr(table, columns):
    """Per row, the largest flux / flux error of the (flux, error) ``columns`` (0 where
    none is finite)."""
    snr = np.zeros(len(table))
    for f_name, e_name in columns:
        f = np.asarray(getattr(table[f_name], "value", table[f_name]), float)
        e = np.asarray(getattr(table[e_name], "value", table[e_name]), float)
        with np.errstate(invalid="ignore", divide="ignore"):
            snr = np.fmax(snr, np.where(np.isfinite(f / e), f / e, 0.0))
    return snr


def _significant(cat, bands, arc):
    """The rows of a catalogue significant in at least one band (warning for the rest)."""
    from .exceptions import LensdualWarning

    snr = _best_snr(cat, [(f"flux_{band}", f"flux_err_{band}") for band in bands])
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
        for arc in ARCS:
            flux = measured[flux_col(arc, band)]
            values = np.asarray(getattr(flux, "value", flux), dtype=float)
            with np.errstate(invalid="ignore"):
                bad = np.isfinite(values) & (values <= 0)
            add_doubt(doubt, bad, lambda k, arc=arc, band=band, values=values: (
                f"non-positive flux on L{arc} in {band} ({values[k]:.3g}): blank sky or a "
                "spurious detection"))
            if bad.any():
                for col in (flux_col(arc, band), flux_err_col(arc, band)):
                    measured[col][bad] = np.nan * getattr(measured[col], "unit", 1)


def _doubt_faint(measured, bands, doubt):
    """A pair whose image on an arc was measured but is below ``_MIN_CANDIDATE_SNR``
    sigma in every band is no point source there (blank sky, a spurious candidate):
    doubtful (in place), so that it is left out of the others' size magnifications."""
    for arc in ARCS:
        columns = [(flux_col(arc, band), flux_err_col(arc, band)) for band in bands]
        snr = _best_snr(measured, columns)
        seen = np.zeros(len(measured), bool)
        for name, _ in columns:
            seen |= np.isfinite(np.asarray(getattr(measured[name], "value", measured[name]),
                                           dtype=float))
        add_doubt(doubt, seen & (snr < _MIN_CANDIDATE_SNR), lambda k, arc=arc, snr=snr: (
            f"no point source on L{arc}: its PSF flux is below {_MIN_CANDIDATE_SNR:g} sigma "
            f"in every band (at most {snr[k]:.1f} sigma): blank sky or a spurious candidate"))


def _add_null_calibration(result, measured, sigma, n_realisations, snr_threshold, seed,
                          test=DEFAULT_TEST, snr_definition=DEFAULT_SNR_DEFINITION):
    """Run the null calibration and record it in ``result`` (in place)."""
    from .duality import null_calibration

    null = null_calibration(measured, sigma_pos=sigma, n_realisations=n_realisations,
                            snr_threshold=snr_threshold, seed=seed, test=test,
                            snr_definition=snr_definition)
    result["p_value_empirical"] = null["p_value_empirical"]
    keys = ("n_realisations", "false_alarm_rate", "nominal_false_alarm_rate",
            "expected_false_flags", "p_any_false_flag", "family_wise_p_empirical",
            "map", "map_dof", "map_chi2_dof", "map_interpolates")
    result.meta["duality"]["null_calibration"] = {k: null.meta[k] for k in keys}


# ---------------------------------------------------------------------------
# the catalogue-only (knots) analysis
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class KnotAnalysis:
    """Result of :func:`analyse_knots`.

    Parameters
    ----------
    knot_pairs : `~lensdual.pairing.KnotPairs`
        The pairs tables and the fate of every knot image.
    tables : dict
        ``(macro1, macro2) -> QTable``: the output of
        :func:`~lensdual.parametric.compare_size_with_models` (``mu_size`` and
        every model's ratio per knot), or of
        :func:`~lensdual.estimators.size_magnification` plus the knot ids
        without models.
    sigma_pos : dict
        ``(macro1, macro2) -> Quantity``: the position error used.
    sigma_degree : dict
        ``(macro1, macro2) -> int``: the degree of the residual fit that measured
        it (0 when ``sigma_pos`` was given).
    models : dict
        ``name -> LenstoolModel`` compared with.
    """

    knot_pairs: object
    tables: dict
    sigma_pos: dict
    sigma_degree: dict
    models: dict = field(default_factory=dict)


def _model_name(path, taken):
    p = Path(path)
    name = "".join(c if c.isalnum() else "_" for c in (p.parent.name or p.stem)) or "model"
    base, k = name, 2
    while name in taken:
        name, k = f"{base}_{k}", k + 1
    return name


def analyse_knots(catalogue, macro_images, *, knots=None, assign=None, mapping=None, models=(),
                  z_source=None, sigma_pos="auto", method=DEFAULT_METHOD,
                  snr_threshold=DEFAULT_SNR_THRESHOLD):
    """Knot constellation of a catalogue: pairs, ``mu_size`` and model ratios.

    Parameters
    ----------
    catalogue : str, os.PathLike or `~astropy.table.Table`
        The multiple-image catalogue (see
        :func:`~lensdual.pairing.pairs_from_knots`).
    macro_images : dict, table or list of str
        The macro-images: ``{name: SkyCoord}``, or names (then their centres
        are the commented lines of a Lenstool ``catalogue`` of those ids,
        unless a mapping assigns the images).
    knots, assign, mapping, z_source
        As in :func:`~lensdual.pairing.pairs_from_knots`.
    models : sequence or dict of `~lensdual.parametric.LenstoolModel` or paths
        Lens models to compare with; paths are read with
        :func:`~lensdual.parametric.read_lenstool`. The first assigns the
        images when ``assign="model"`` (the default with models).
    sigma_pos : `~astropy.units.Quantity` or "auto"
        Position error per coordinate; ``"auto"`` measures it for every pair
        of macro-images with :func:`~lensdual.estimators.estimate_sigma_pos`.
    method : str
        Size-magnification estimator (default ``"adaptive"``).
    snr_threshold : float
        A knot disagrees with a model beyond this SNR (default 3).

    Returns
    -------
    `KnotAnalysis`
        The pairs of every pair of macro-images, their ``mu_size`` and, with
        models, the models' ratios.

    Examples
    --------
    >>> import astropy.units as u
    >>> from astropy.coordinates import SkyCoord
    >>> from astropy.table import QTable
    >>> import numpy as np
    >>> from lensdual.pipeline import analyse_knots
    >>> c = SkyCoord(150 * u.deg, 2 * u.deg)
    >>> rng = np.random.default_rng(0)
    >>> src = rng.uniform(-1, 1, (12, 2))
    >>> a_map, b_map = np.array([[2.0, 0.3], [0.1, 1.5]]), np.array([[1.2, 0.0], [0.2, -0.9]])
    >>> xy = np.vstack([src @ a_map.T + [-10, 0], src @ b_map.T + [10, 0]])
    >>> xy += 0.01 * rng.standard_normal(xy.shape)
    >>> ids = [f"{k}.1" for k in range(12)] + [f"{k}.2" for k in range(12)]
    >>> sky = c.spherical_offsets_by(-xy[:, 0] * u.arcsec, xy[:, 1] * u.arcsec)
    >>> res = analyse_knots(QTable({"id": ids, "sky": sky}),
    ...                     {"A": c.spherical_offsets_by(10 * u.arcsec, 0 * u.arcsec),
    ...                      "B": c.spherical_offsets_by(-10 * u.arcsec, 0 * u.arcsec)})
    >>> tab = res.tables[("A", "B")]
    >>> truth = abs(np.linalg.det(a_map) / np.linalg.det(b_map))
    >>> bool(np.all(np.abs(np.log(tab["mu_size"] / truth)) < 4 * tab["ln_mu_size_err"]))
    True
    """
    import os

    from .pairing import pairs_from_knots, read_macro_images
    from .parametric import LenstoolModel, compare_size_with_models, read_lenstool

    if isinstance(models, dict):
        items = list(models.items())
    else:
        items, taken = [], set()
        for m in ([models] if isinstance(models, (str, os.PathLike, LenstoolModel)) else models):
            name = _model_name(m.path if isinstance(m, LenstoolModel) else m, taken)
            taken.add(name)
            items.append((name, m))
    loaded = {name: (m if isinstance(m, LenstoolModel) else read_lenstool(m)) for name, m in items}
    first = next(iter(loaded.values()), None)
    if (isinstance(macro_images, (list, tuple)) and mapping is None
            and isinstance(catalogue, (str, os.PathLike))):
        macro_images = read_macro_images(catalogue, macro_images)
    if assign is None and mapping is None and first is not None:
        assign = "model"
    kp = pairs_from_knots(catalogue, macro_images, knots=knots, assign=assign, mapping=mapping,
                          model=first if assign == "model" else None, z_source=z_source)
    snr_threshold = as_real(snr_threshold, "snr_threshold", minimum=0.0)
    fixed = None if isinstance(sigma_pos, str) and sigma_pos == "auto" else (
        as_angle_scalar(sigma_pos, "sigma_pos", allow_zero=False) * u.arcsec)
    tables, sigmas, degrees = {}, {}, {}
    for key, tab in kp.pairs.items():
        t1, t2 = arc_xy(tab, 1), arc_xy(tab, 2)
        if fixed is None:
            sigma, degree, _ = estimate_sigma_pos(t1 * u.arcsec, t2 * u.arcsec, full_output=True)
        else:
            sigma, degree = fixed, 0
        sigmas[key], degrees[key] = sigma, degree
        if loaded:
            tables[key] = compare_size_with_models(tab, loaded, sigma_pos=sigma,
                                                   z_source=z_source, method=method,
                                                   snr_threshold=snr_threshold)
        else:
            from .estimators import size_magnification

            size = size_magnification(t1 * u.arcsec, t2 * u.arcsec, method=method,
                                      sigma_pos=sigma)
            for c in ("knot", "id1", "id2"):
                size[c] = tab[c]
            size.meta.update(macro1=key[0], macro2=key[1], models=[])
            tables[key] = size
    return KnotAnalysis(knot_pairs=kp, tables=tables, sigma_pos=sigmas, sigma_degree=degrees,
                        models=loaded)

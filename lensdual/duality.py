"""The per-pair test of geometrical duality (paper Sect. 3.3 and 5.1.1).

For a point-source pair imaged on arcs L1 and L2, lensing conserves surface
brightness, so the flux ratio ``mu_flux = F(L1) / F(L2)`` must equal the size
magnification ``mu_size = |det J|`` estimated from the constellation's
geometry. :func:`check_duality` measures both, with errors, and flags the pairs
where they disagree.
"""

import warnings
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np
from astropy import units as u
from astropy.table import QTable, Table
from scipy import stats
from scipy.special import chdtrc, erfc

from . import _pairs_table, _profile_kernels
from ._doubts import add_doubt, doubts_of
from ._null_map import spline_map
from ._pairs_table import band_fluxes as _band_fluxes
from ._pairs_table import pair_bands
from ._pairs_table import positions as _positions
from ._parallel import available_threads as _available_threads
from ._parallel import check_client, run_tasks
from ._validation import as_int, as_real
from .estimators import DEFAULT_METHOD, DEFAULT_N_BOOTSTRAP, TESTABLE_STATUS, size_magnification
from .estimators.core import FEW_PAIRS_HINT, determined_parity
from .exceptions import LensdualWarning

__all__ = ["POSITION_COLUMNS", "SNR_DEFINITIONS", "LOG_SNR_DEFINITIONS", "TESTS",
           "check_duality", "pair_bands",
           "flux_ratios", "holm_adjust", "null_calibration", "gaussian_p_value",
           "duality_significance", "DEFAULT_SNR_THRESHOLD", "DEFAULT_TEST",
           "DEFAULT_SNR_DEFINITION", "resolve_test", "resolve_snr_definition",
           "check_test_settings"]

#: Position columns every pairs table needs (arcsec or any angle unit).
POSITION_COLUMNS = _pairs_table.POSITION_COLUMNS

#: The default flag threshold of :func:`check_duality` (a significance of 3:
#: 0.27 % false alarms per pair), also that of ``lensdual run``.
DEFAULT_SNR_THRESHOLD = 3.0

#: Definitions of the duality signal-to-noise ratio, see :func:`check_duality`.
SNR_DEFINITIONS = ("log", "paper", "profile", "conservative")

#: The definitions whose anomalies are ``ln`` ratios with the flux ratio's error
#: combined: those the joint test, the null calibration and the abundance
#: posterior take.
LOG_SNR_DEFINITIONS = ("log", "conservative")

# the definitions that read the adaptive Jacobian's covariance
_PROFILE_DEFINITIONS = ("profile", "conservative")

#: The tests of :func:`check_duality`: ``"geometric"`` (the flux ratio against
#: ``mu_size``) and ``"joint"`` (against ``mu_size`` and the neighbours' flux
#: ratios together, see :mod:`lensdual.flux_field`).
TESTS = ("geometric", "joint")

#: The default test of :func:`check_duality`, :func:`null_calibration` and
#: ``lensdual run``: ``"auto"``, see :func:`resolve_test`.
DEFAULT_TEST = "auto"

#: The default SNR definition of :func:`check_duality`,
#: :func:`null_calibration` and ``lensdual run``: ``"auto"``, see
#: :func:`resolve_snr_definition`.
DEFAULT_SNR_DEFINITION = "auto"


def resolve_test(test, method, bands, snr_definition="conservative", n_pairs=None):
    """The test that ``test`` names for ``method``, ``bands``, ``snr_definition``
    and ``n_pairs``.

    Parameters
    ----------
    test : {"auto", "geometric", "joint"}
        ``"auto"`` is ``"joint"`` where the joint test applies (method
        ``"adaptive"``, at least two bands of fluxes, an SNR definition of
        :data:`LOG_SNR_DEFINITIONS`, see :func:`check_duality`, and at least
        :data:`lensdual.flux_field.MIN_PAIRS` pairs with flux ratios, below
        which the flux field predicts no pair) and ``"geometric"``
        elsewhere. ``"geometric"`` and ``"joint"`` stand for themselves.
    method : str
        The size-magnification estimator.
    bands : sequence of str
        The bands with fluxes (:func:`pair_bands`).
    snr_definition : str
        The SNR definition, resolved (:func:`resolve_snr_definition`).
    n_pairs : int, optional
        The pairs with flux ratios (None: not known yet, enough).

    Returns
    -------
    test : {"geometric", "joint"}

    Examples
    --------
    >>> from lensdual.duality import resolve_test
    >>> resolve_test("auto", "adaptive", ["F150W", "F200W"])
    'joint'
    >>> resolve_test("auto", "adaptive", ["F150W"])
    'geometric'
    """
    if not isinstance(test, str) or test not in ("auto",) + TESTS:
        raise ValueError(f"test must be one of {['auto', *TESTS]}, got {test!r}")
    if test != "auto":
        return test
    return "geometric" if _why_not_joint(method, bands, snr_definition, n_pairs) else "joint"


def _why_not_joint(method, bands, snr_definition, n_pairs):
    """Why the joint test does not apply, in words ("" where it does): see
    :func:`resolve_test`."""
    from .flux_field import MIN_PAIRS

    if method != "adaptive":
        return f"the joint test needs the adaptive estimator, not {method}"
    if len(bands) < 2:
        return ("the joint test needs flux ratios in two bands (the chromatic check keeps "
                "mis-paired sources out of the neighbours' field); the table has them in "
                f"{'one' if len(bands) == 1 else 'none'}")
    if snr_definition not in LOG_SNR_DEFINITIONS:
        return f"the joint test takes the log or conservative SNR, not {snr_definition}"
    if n_pairs is not None and n_pairs < MIN_PAIRS:
        return (f"the neighbours' flux field needs flux ratios of at least {MIN_PAIRS} "
                f"pairs to predict any; the table has {n_pairs}")
    return ""


def resolve_snr_definition(snr_definition, method):
    """The SNR definition that ``snr_definition`` names for ``method``.

    Parameters
    ----------
    snr_definition : {"auto", "log", "paper", "profile", "conservative"}
        ``"auto"`` is ``"conservative"`` for method ``"adaptive"`` (the
        smaller of the linearised and the profile-likelihood SNR: the one
        whose false flags hold on compact galaxy-scale folds, at most a point
        of power elsewhere under the joint test, see the calibration pages)
        and ``"log"`` for the other estimators, which have no Jacobian
        covariance. The others stand for themselves.
    method : str
        The size-magnification estimator.

    Returns
    -------
    snr_definition : str
        One of :data:`SNR_DEFINITIONS`.

    Examples
    --------
    >>> from lensdual.duality import resolve_snr_definition
    >>> resolve_snr_definition("auto", "adaptive")
    'conservative'
    >>> resolve_snr_definition("auto", "quad")
    'log'
    """
    if not isinstance(snr_definition, str) or snr_definition not in ("auto",) + SNR_DEFINITIONS:
        raise ValueError(f"snr_definition must be one of {['auto', *SNR_DEFINITIONS]}, got "
                         f"{snr_definition!r}")
    if snr_definition != "auto":
        return snr_definition
    return "conservative" if method == "adaptive" else "log"

#: Most passes of the joint test's exclusion of flagged neighbours.
_JOINT_MAX_PASSES = 6


def _as_qtable(pairs):
    if not isinstance(pairs, Table):
        raise TypeError(
            "pairs must be an astropy Table or QTable (the pairs table), got "
            f"{type(pairs).__name__}"
        )
    return QTable(pairs, copy=True)


def flux_ratios(pairs):
    """Flux ratios ``F(L1)/F(L2)`` per band and combined over bands.

    Per band, the ratio's logarithmic error is
    ``sqrt((e1/F1)**2 + (e2/F2)**2)`` (first-order propagation). The bands are
    combined by the inverse-variance weighted mean of ``ln mu_flux``; a
    lensed pair has the same ratio in every band, so the chi-square of the
    band ratios about that mean (``chromatic_chi2``, ``nbands - 1`` degrees
    of freedom) tests the pairing. A NaN flux means "not measured in that
    band": the band is left out for that pair.

    Parameters
    ----------
    pairs : `~astropy.table.Table`
        Pairs table with ``flux1_<band>``, ``flux2_<band>``, ``flux_err1_<band>``
        and ``flux_err2_<band>`` for every band of :func:`pair_bands`.

    Returns
    -------
    table : `~astropy.table.QTable`
        Columns ``mu_flux_<band>``, ``mu_flux_err_<band>`` per band, then
        ``mu_flux``, ``mu_flux_err``, ``ln_mu_flux_err``, ``chromatic_chi2``,
        ``chromatic_dof`` and ``chromatic_pvalue``.

    Examples
    --------
    Two pairs measured in two bands: the first has the same flux ratio in
    both, the second does not (a chromatic pair, most likely not two images
    of one source):

    >>> import numpy as np
    >>> from astropy.table import QTable
    >>> from lensdual.duality import flux_ratios
    >>> pairs = QTable({"flux1_F150W": [200.0, 200.0], "flux2_F150W": [100.0, 100.0],
    ...                 "flux_err1_F150W": [2.0, 2.0], "flux_err2_F150W": [1.0, 1.0],
    ...                 "flux1_F277W": [300.0, 600.0], "flux2_F277W": [150.0, 150.0],
    ...                 "flux_err1_F277W": [3.0, 6.0], "flux_err2_F277W": [1.5, 1.5]})
    >>> ratios = flux_ratios(pairs)
    >>> ratios["mu_flux_F150W"].tolist(), ratios["mu_flux_F277W"].tolist()
    ([2.0, 2.0], [2.0, 4.0])
    >>> np.round(ratios["chromatic_pvalue"], 3).tolist()
    [1.0, 0.0]
    """
    tab = _as_qtable(pairs)
    bands = pair_bands(tab)
    n = len(tab)
    out = QTable()
    ln_mu = np.full((len(bands), n), np.nan)
    ln_err = np.full((len(bands), n), np.nan)
    for i, band in enumerate(bands):
        f1, f2, e1, e2 = _band_fluxes(tab, band)
        mu = f1 / f2
        s = np.hypot(e1 / f1, e2 / f2)
        out[_pairs_table.mu_flux_col(band)] = mu
        out[_pairs_table.mu_flux_err_col(band)] = mu * s
        ln_mu[i] = np.log(mu)
        ln_err[i] = s
    valid = np.isfinite(ln_mu)
    w = np.where(valid, 1.0 / np.where(valid, ln_err, 1.0) ** 2, 0.0)
    wsum = w.sum(axis=0)
    nvalid = valid.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(wsum > 0, (w * np.where(valid, ln_mu, 0.0)).sum(axis=0) / wsum, np.nan)
        sig = np.where(wsum > 0, 1.0 / np.sqrt(wsum), np.nan)
    chi2 = (w * np.where(valid, ln_mu - mean, 0.0) ** 2).sum(axis=0)
    dof = np.maximum(nvalid - 1, 0)
    chi2 = np.where(nvalid > 0, chi2, np.nan)
    pvalue = np.where(dof > 0, chdtrc(np.maximum(dof, 1), chi2), np.nan)
    if (nvalid == 0).any():
        warnings.warn(
            f"no band has a finite flux ratio for row(s) {np.flatnonzero(nvalid == 0).tolist()};"
            " their mu_flux is NaN",
            LensdualWarning,
            stacklevel=2,
        )
    out["mu_flux"] = np.exp(mean)
    out["mu_flux_err"] = np.exp(mean) * sig
    out["ln_mu_flux_err"] = sig
    out["chromatic_chi2"] = chi2
    out["chromatic_dof"] = dof
    out["chromatic_pvalue"] = pvalue
    return out


def gaussian_p_value(snr):
    """Two-sided Gaussian p-value of a duality SNR: ``P(|Z| >= snr)``.

    Under the null (duality holds, errors Gaussian in ``ln``), the SNR of
    :func:`check_duality` is ``|Z|`` with ``Z`` standard normal; SNR 3 gives
    0.27 %.

    Parameters
    ----------
    snr : array_like
        Non-negative SNRs (or significances).

    Returns
    -------
    p_value : `~numpy.ndarray`
        ``P(|Z| >= snr)``, same shape as ``snr``.

    Examples
    --------
    >>> from lensdual.duality import gaussian_p_value
    >>> gaussian_p_value([1.0, 3.0])  # doctest: +FLOAT_CMP
    array([0.31731051, 0.0026998 ])
    """
    snr = np.asarray(snr, dtype=float)
    return erfc(snr / np.sqrt(2.0))


def _t_p_value(snr, dof):
    """Two-sided p-value of ``snr`` under Student's t with ``dof`` degrees of
    freedom (Gaussian where ``dof`` is infinite)."""
    snr = np.asarray(snr, dtype=float)
    dof = np.broadcast_to(np.asarray(dof, dtype=float), snr.shape)
    gauss = ~(dof < np.inf)
    with np.errstate(invalid="ignore"):
        p = np.where(gauss, erfc(snr / np.sqrt(2.0)),
                     2.0 * stats.t.sf(snr, np.where(gauss, 1.0, dof)))
    return p


def _snr_dof(ln_total, ln_size_err, size_dof):
    """Welch-Satterthwaite degrees of freedom of a duality SNR's error.

    ``ln_total`` is ``hypot(ln flux error, ln_size_err)``: the flux error is
    known, the size error estimated from ``size_dof`` residuals (infinite:
    known too, and so is the total).
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(size_dof < np.inf, ln_total**4 * size_dof / ln_size_err**4, np.inf)


def duality_significance(snr, dof=np.inf):
    """Gaussian-equivalent significance of a duality SNR whose error has ``dof``
    degrees of freedom.

    A pair's SNR, ``|ln R| / sigma``, follows a standard normal under the
    null only when ``sigma`` is known. Where part of ``sigma`` is itself
    estimated from ``dof`` residuals (the ``"misfit"`` pairs of the adaptive
    estimator), it follows Student's t with ``dof`` degrees of freedom; its
    two-sided p-value is converted back to the SNR a Gaussian statistic
    would need for the same p-value, so that one threshold means one
    false-alarm probability for every pair.

    Parameters
    ----------
    snr : array_like
        Non-negative SNRs (NaN allowed).
    dof : array_like
        Degrees of freedom of each SNR's error, broadcast against ``snr``;
        ``inf`` (default) for a known error, where the significance equals
        the SNR. Must be positive (NaN allowed: the significance is NaN).

    Returns
    -------
    significance : `~numpy.ndarray`
        ``Phi^-1(1 - p / 2)``, ``p`` the two-sided t p-value; at most ``snr``.

    Examples
    --------
    >>> from lensdual.duality import duality_significance
    >>> float(duality_significance(3.0))
    3.0
    >>> round(float(duality_significance(3.0, dof=4)), 2)
    2.05
    """
    snr = np.asarray(snr, dtype=float)
    dof = np.asarray(dof, dtype=float)
    if np.any(dof <= 0):
        raise ValueError("dof must be positive (inf for a known error)")
    dof = np.broadcast_to(dof, snr.shape)
    p = _t_p_value(snr, dof)
    with np.errstate(invalid="ignore"):
        out = np.where(~(dof < np.inf), snr, stats.norm.isf(0.5 * p))
    return out


def holm_adjust(p_values):
    """Holm-Bonferroni adjusted p-values (family-wise error control).

    A pair whose adjusted p-value is below ``alpha`` is significant with a
    probability of at least one false rejection among all pairs of at most
    ``alpha``, whatever the correlation between the pairs. NaN entries
    (untested pairs) stay NaN and do not count in the family.

    Parameters
    ----------
    p_values : array_like, shape (N,)

    Returns
    -------
    adjusted : `~numpy.ndarray`, shape (N,)

    Examples
    --------
    >>> import numpy as np
    >>> from lensdual.duality import holm_adjust
    >>> holm_adjust([0.01, 0.04, 0.03, np.nan])
    array([0.03, 0.06, 0.06,  nan])
    """
    p = np.asarray(p_values, dtype=float)
    if p.ndim != 1:
        raise ValueError(f"p_values must be one-dimensional, got shape {p.shape}")
    out = np.full(p.shape, np.nan)
    ok = np.flatnonzero(np.isfinite(p))
    if ok.size == 0:
        return out
    m = ok.size
    order = ok[np.argsort(p[ok], kind="stable")]
    adj = np.minimum(1.0, (m - np.arange(m)) * p[order])
    out[order] = np.maximum.accumulate(adj)
    return out


def _family_summary(p_values, snr_threshold):
    """Expected false flags and family-wise probabilities under the null.

    ``p_values`` are the tested pairs' p-values, NaN for the others.
    """
    n_tested = int(np.count_nonzero(np.isfinite(p_values)))
    p_thr = float(gaussian_p_value(snr_threshold))
    p_min = float(np.nanmin(p_values)) if n_tested else np.nan
    return {
        "n_tested": n_tested,
        "p_threshold": p_thr,
        "expected_false_flags": n_tested * p_thr,
        "p_any_false_flag": 1.0 - (1.0 - p_thr) ** n_tested,
        "family_wise_p": (1.0 - (1.0 - p_min) ** n_tested) if n_tested else np.nan,
    }


#: Default false-alarm probability of the chromatic check of check_duality.
CHROMATIC_ALPHA = 1e-3


def _doubts(tab, theta1, theta2, flux, chromatic_alpha):
    """Why each pair is doubtful ("" when it is not): the input's ``doubt`` column,
    then the chromatic check."""
    doubt = doubts_of(tab)
    lost = ~(np.isfinite(theta1.value).all(axis=1) & np.isfinite(theta2.value).all(axis=1))
    add_doubt(doubt, lost, "position not measured (NaN)")
    pval = np.asarray(flux["chromatic_pvalue"], dtype=float)
    with np.errstate(invalid="ignore"):
        chroma = pval < chromatic_alpha
    add_doubt(doubt, chroma, lambda k: (f"colours differ between the images (chromatic p = "
                                        f"{pval[k]:.2g}): lensing is achromatic"))
    return doubt.astype(str)


def _without_doubtful_fluxes(flux, flux_doubt):
    """``flux`` with NaN in every float column of the pairs whose flux ratio is
    doubtful: they inform no test (nor the chromatic check, nor the joint test's flux
    field)."""
    held = flux_doubt != ""
    if not held.any():
        return flux
    out = flux.copy()
    for name in out.colnames:
        if np.issubdtype(np.asarray(out[name]).dtype, np.floating):
            out[name][held] = np.nan  # NaN takes any unit
    return out


def _chromatic_hint(doubt):
    """Where most pairs are chromatic, what that usually means."""
    chromatic = np.char.startswith(np.asarray(doubt, dtype=str), "colours differ")
    if 2 * int(chromatic.sum()) <= doubt.size:
        return ""
    return (f". {int(chromatic.sum())} of the {doubt.size} pairs have band ratios that differ "
            "between the images: check that each band names the same filter on both arcs "
            "(bands swapped on one arc make every coloured source chromatic); another "
            "estimator would not help")


def _doubt_list(tab, doubt):
    ids = np.asarray(tab["pair_id"]) if "pair_id" in tab.colnames else np.arange(1, len(tab) + 1)
    return "; ".join(f"pair {i}: {d}" for i, d in zip(ids, doubt, strict=True) if d)


def _subset_sigma(sigma_pos, keep):
    """``sigma_pos`` restricted to the kept pairs (scalars pass through)."""
    if keep.all() or not isinstance(sigma_pos, u.Quantity) or sigma_pos.ndim == 0:
        return sigma_pos
    if sigma_pos.shape[-1] != keep.size:
        return sigma_pos  # the estimator reports the shape mismatch
    return sigma_pos[..., keep]


def _expand(size, keep):
    """The size table of the kept pairs, back on all rows (NaN, status 'excluded')."""
    if keep.all():
        return size
    out = QTable()
    idx = np.flatnonzero(keep)
    for name in size.colnames:
        col = size[name]
        if name == "mu_size_status":
            full = np.full(keep.size, "excluded", dtype=object)
            full[idx] = np.asarray(col, dtype=object)
            out[name] = full.astype(str)
            continue
        values = np.asarray(col.value if isinstance(col, u.Quantity) else col)
        shape = (keep.size,) + values.shape[1:]
        full = (np.zeros(shape, dtype=values.dtype) if values.dtype.kind in "iub"
                else np.full(shape, np.nan, dtype=float))
        full[idx] = values
        out[name] = full * col.unit if isinstance(col, u.Quantity) else full
    out.meta.update(size.meta)
    return out


def check_duality(
    pairs,
    method=DEFAULT_METHOD,
    *,
    sigma_pos=0.06 * u.arcsec,
    n_bootstrap=DEFAULT_N_BOOTSTRAP,
    snr_threshold=DEFAULT_SNR_THRESHOLD,
    seed=None,
    snr_definition=DEFAULT_SNR_DEFINITION,
    weight_power=2,
    min_angle=5 * u.deg,
    chromatic_alpha=CHROMATIC_ALPHA,
    test=DEFAULT_TEST,
):
    r"""Test geometrical duality, ``mu_flux = mu_size``, for every pair.

    Parameters
    ----------
    pairs : `~astropy.table.Table` or `~astropy.table.QTable`
        The pairs table (:ref:`pairs-table`): positions ``x1, y1, x2, y2``
        (angles, one common frame) and, for every band, ``flux1_<band>``,
        ``flux2_<band>``, ``flux_err1_<band>``, ``flux_err2_<band>``. The
        bands are ``meta['bands']`` or, without it, every ``flux1_<band>``.
        It is not modified.
    method : {"adaptive", "quad", "2v", "quad2"}
        Size-magnification estimator, see
        :func:`~lensdual.estimators.size_magnification` (default
        ``"adaptive"``, the only one whose errors include the estimator's
        own truncation error).
    sigma_pos : `~astropy.units.Quantity`
        Positional uncertainty for the bootstrap of ``mu_size`` (default
        0.06 arcsec), see :func:`~lensdual.estimators.size_magnification`.
    n_bootstrap : int
        Bootstrap realisations (default 1000).
    snr_threshold : float
        A pair is ``anomalous`` when its significance (the Gaussian
        equivalent of its SNR, below) exceeds this (default 3): the
        false-alarm probability per pair is that of ``|Z| > snr_threshold``
        for every pair.
    seed : int, `numpy.random.Generator` or None
        Seed of the bootstrap.
    snr_definition : {"auto", "log", "paper", "profile", "conservative"}
        Which SNR sets ``anomalous``. ``"auto"`` (default):
        ``"conservative"`` for method ``"adaptive"``, ``"log"`` for the
        others (:func:`resolve_snr_definition`). ``"log"``:
        :math:`|\ln R| / \sqrt{\sigma_{\ln F}^2 + \sigma_{\ln S}^2}` with
        :math:`R` = ``duality_ratio``, :math:`\sigma_{\ln F}` the error of
        :math:`\ln \mu_{\rm flux}` and :math:`\sigma_{\ln S}` half the 16-84 %
        width of the bootstrap distribution of :math:`\ln \mu_{\rm size}`;
        both errors count, and the statistic is symmetric between a brighter
        L1 and a brighter L2 image. ``"paper"``: the paper's Sect. 5.2.3
        definition, :math:`|R - 1| / (R\,\sigma_{\mu_{\rm size}}/\mu_{\rm size})`,
        size error only. Both are always returned (``snr`` and ``snr_paper``).
        ``"profile"`` (method ``"adaptive"`` only): the profile-likelihood
        SNR of the hypothesis ``|det J| = mu_flux``, the distance from the
        estimated Jacobian (with its covariance ``jacobian_cov``) and the
        flux ratio to that hypothesis, in the column ``snr_profile`` (the
        Jacobian's covariance it reads in ``jacobian_cov``); it
        equals ``"log"`` where the error of ``ln mu_size`` is small and does
        not assume ``mu_size`` log-normal where it is large (see
        :ref:`profile-snr`). Its degrees of freedom are those of ``"log"``.
        ``"conservative"`` (method ``"adaptive"`` only): the smaller of the
        ``"log"`` and ``"profile"`` SNRs (the ``"log"`` one where the pair's
        Jacobian covariance gives no profile), so that a pair is flagged only
        where both reject; for lenses whose magnification ratio varies
        several-fold over the constellation (compact galaxy-scale arcs),
        where the ``"log"`` SNR over-flags (see :ref:`profile-snr`); elsewhere
        it costs at most a point of power.
    weight_power, min_angle
        Estimator settings, see :func:`~lensdual.estimators.relative_jacobian`.
    chromatic_alpha : float
        Lensing is achromatic: the two images of one source have the same
        flux ratio in every band. A pair whose band ratios disagree beyond
        this false-alarm probability (``chromatic_pvalue < chromatic_alpha``,
        default 1e-3) is *doubtful*: most likely two different sources, a
        blend, or differential extinction, and never evidence of a sub-halo.
        0 turns the check off.
    test : {"auto", "geometric", "joint"}
        ``"geometric"``: the flux ratio is tested against ``mu_size``.
        ``"joint"``: against ``mu_size`` and the flux-field prediction of the
        other pairs' flux ratios combined (inverse-variance weighted), see
        :ref:`joint-test`; it needs method "adaptive" (the field is predicted
        only where the adaptive fits of the pair and its neighbours passed
        their chi-square tests), at least two bands (the chromatic check
        keeps mis-pairs out of the field) and snr_definition "log" or
        "conservative". The columns it adds are listed below. ``"auto"``
        (default): ``"joint"`` where it applies, ``"geometric"`` elsewhere
        (:func:`resolve_test`); ``meta['duality']['test']`` and
        ``['snr_definition']`` say which ran, and ``['test_auto']`` why
        ``"auto"`` ran the geometric test.

    Returns
    -------
    result : `~astropy.table.QTable`
        A copy of ``pairs`` with these columns appended (replaced if present):
        ``jacobian``, ``parity`` (the sign of ``det J`` where it is
        determined, 0 where ``parity_snr``, its significance ``1 /
        ln_mu_size_err``, is below ``snr_threshold`` or the pair is
        untestable), ``parity_snr``, ``mu_size``, ``mu_size_err``,
        ``mu_size_p16``, ``mu_size_p84``, ``mu_flux_<band>``,
        ``mu_flux_err_<band>``, ``mu_flux``, ``mu_flux_err``,
        ``chromatic_chi2``, ``chromatic_dof``, ``chromatic_pvalue``,
        ``duality_ratio`` (``mu_flux / mu_size``), ``duality_ratio_err``,
        ``snr``, ``snr_paper``, ``snr_dof``, ``significance``, ``tested``,
        ``p_value``, ``p_value_holm`` and ``anomalous``; also
        ``ln_mu_size_err``, ``ln_mu_size_err_dof`` and ``mu_size_status``.
        ``tested`` is False where the pair could not be tested (no finite
        SNR, or ``mu_size_status`` ``"untestable"`` or ``"failed"``); such
        pairs are never ``anomalous`` and have NaN p-values. Pairs whose
        adaptive status is ``"misfit"`` are tested with their widened
        errors, which are estimated from ``ln_mu_size_err_dof`` residuals:
        their SNR follows Student's t with ``snr_dof`` degrees of freedom
        (Welch-Satterthwaite, the flux error being known; infinite, i.e.
        Gaussian, for ``"ok"`` pairs and the bootstrap methods), and
        ``significance`` is its Gaussian equivalent
        (:func:`duality_significance`; equal to the SNR where ``snr_dof``
        is infinite). See the calibration page for how that holds.
        ``p_value`` is the two-sided p-value of the SNR (Gaussian, or
        Student's t),
        ``p_value_holm`` its Holm-Bonferroni adjustment over the tested
        pairs (:func:`holm_adjust`). A ``pair_id`` column (from 1) is added
        when missing. ``meta['duality']`` records the settings
        (``reverse_map_pairs``, for ``"adaptive"``: the ``pair_id`` of the
        pairs whose Jacobian came from the L1-to-L2 map, see
        :func:`~lensdual.estimators.size_magnification`) and the
        calibration of the family of tests: ``n_tested``, ``n_flagged``,
        ``p_threshold`` (the false-alarm probability of one pair at the
        threshold), ``expected_false_flags`` (``n_tested * p_threshold``),
        ``p_any_false_flag`` (the chance of at least one flag among the
        tested pairs without any sub-halo, ``1 - (1 - p_threshold)**n``) and
        ``family_wise_p`` (the chance, without any sub-halo, of at least one
        pair as discrepant as the most discrepant one, Sidak-corrected).
        For an empirical calibration of the same numbers on a simulated
        null like the user's constellation, see :func:`null_calibration`.

        With ``test="joint"``, ``snr``, ``snr_dof``, ``significance``,
        ``tested``, ``p_value``, ``p_value_holm`` and ``anomalous`` are the
        joint test's, and these columns are added: ``significance_geometric``,
        ``snr_dof_geometric`` and ``anomalous_geometric`` (the geometric
        test's), ``ln_mu_field``,
        ``ln_mu_field_err``, ``field_status``, ``field_n``, ``field_dropped`` (see
        :func:`~lensdual.flux_field.flux_field_prediction`),
        ``field_consistency`` (the significance of the difference between
        ``ln mu_size`` and ``ln_mu_field``), ``ln_mu_predicted`` and
        ``ln_mu_predicted_err`` (the inverse-variance combination of the two
        that the flux ratio is tested against, and its error; NaN where
        untested), ``smooth_field_fails`` (that
        significance above ``snr_threshold``: the geometry and the neighbours
        disagree, the smooth-field assumption fails at the pair, and it is
        not tested) and ``joint_basis`` (``"geometry+field"``, ``"field"``,
        ``"geometry"``, or ``""`` where neither predicts the pair).
        ``meta['duality']`` adds ``test``, ``field_model_sd`` and
        ``field_excluded_pairs`` (the flagged pairs left out of the others'
        flux field).

    Raises
    ------
    TypeError
        ``pairs`` is not a table, or positions lack angular units.
    ValueError
        Missing columns, a repeated ``pair_id``, non-positive fluxes or flux
        errors, mismatched flux units, and the bad inputs listed in
        :func:`~lensdual.estimators.relative_jacobian`.
    lensdual.exceptions.SameImageError
        Arcs L1 and L2 are one image: every pair's two positions within 1 mas
        of each other (an identity map). It is a ``ValueError``.

    Notes
    -----
    Doubtful pairs (a non-empty ``doubt`` column in ``pairs``, e.g. a pairing
    whose position is off the arc-to-arc map, plus the chromatic check above)
    are left out of the size-magnification estimate of the other pairs, so a
    mis-pair cannot distort the Jacobians of its neighbours, and are not
    tested: their ``mu_size`` is NaN, ``mu_size_status`` is ``"excluded"``
    and ``doubt`` says why. A pair whose flux ratio alone is doubtful (a
    non-empty ``flux_doubt`` column, e.g. light that is not lensed under one
    image, see :ref:`mock-distrust`) keeps its place in the geometry and its
    ``mu_size``; its flux ratio informs no test (its own, the chromatic
    check, the joint test's flux field), and it is not tested.

    Examples
    --------
    Eight pairs of an exactly linear map (``mu_size = 1.23``) whose flux
    ratios obey duality, except pair 4, twice too bright on arc L1:

    >>> import numpy as np
    >>> import astropy.units as u
    >>> from astropy.table import QTable
    >>> rng = np.random.default_rng(1)
    >>> theta2 = rng.uniform(-1, 1, (8, 2))
    >>> theta1 = theta2 @ np.array([[1.5, 0.3], [0.1, -0.8]]).T  # mu_size = 1.23
    >>> flux2 = np.full(8, 100.0)
    >>> flux1 = 1.23 * flux2
    >>> flux1[3] *= 2  # pair 4: twice too bright in L1
    >>> pairs = QTable({"x1": theta1[:, 0] * u.arcsec, "y1": theta1[:, 1] * u.arcsec,
    ...                 "x2": theta2[:, 0] * u.arcsec, "y2": theta2[:, 1] * u.arcsec,
    ...                 "flux1_F150W": flux1, "flux2_F150W": flux2,
    ...                 "flux_err1_F150W": 0.02 * flux1, "flux_err2_F150W": 0.02 * flux2})
    >>> from lensdual.duality import check_duality
    >>> result = check_duality(pairs, sigma_pos=0.005 * u.arcsec)
    >>> np.round(result["duality_ratio"], 3).tolist()
    [1.0, 1.0, 1.0, 2.0, 1.0, 1.0, 1.0, 1.0]
    >>> result["pair_id"][result["anomalous"]].tolist()
    [4]
    >>> result.meta["duality"]["n_tested"], result.meta["duality"]["n_flagged"]
    (8, 1)
    """
    tab = _as_qtable(pairs)
    _pairs_table.check_unique_pair_ids(tab)
    snr_threshold = as_real(snr_threshold, "snr_threshold", minimum=0.0)
    chromatic_alpha = as_real(chromatic_alpha, "chromatic_alpha", minimum=0.0, maximum=1.0)
    bands = pair_bands(tab)
    flux = flux_ratios(tab)  # validates the flux columns before the bootstrap runs
    # the bands with a flux ratio for at least one pair
    measured = [b for b in bands
                if np.isfinite(np.asarray(flux[_pairs_table.mu_flux_col(b)], float)).any()]
    n_flux = int(np.isfinite(np.asarray(flux["mu_flux"], dtype=float)).sum())
    test, snr_definition, why = check_test_settings(test, snr_definition, method, measured,
                                                    n_flux)
    theta1, theta2 = _positions(tab)
    _pairs_table.check_distinct_arcs(tab)
    flux_doubt = doubts_of(tab, "flux_doubt")
    tested_flux = _without_doubtful_fluxes(flux, flux_doubt)
    doubt = _doubts(tab, theta1, theta2, tested_flux, chromatic_alpha)
    keep = doubt == ""
    try:
        size = size_magnification(
            theta1[keep],
            theta2[keep],
            method,
            sigma_pos=_subset_sigma(sigma_pos, keep),
            n_bootstrap=n_bootstrap,
            seed=seed,
            weight_power=weight_power,
            min_angle=min_angle,
        )
    except ValueError as err:
        if keep.all():
            raise
        hint = _chromatic_hint(doubt)
        text = str(err).replace(FEW_PAIRS_HINT, "") if hint else str(err)
        raise ValueError(f"{text} ({int((~keep).sum())} doubtful pair(s) left out of "
                         f"{len(keep)}: {_doubt_list(tab, doubt)}){hint}") from err
    size = _expand(size, keep)

    if "pair_id" not in tab.colnames:
        tab.add_column(np.arange(1, len(tab) + 1), name="pair_id", index=0)
    for name in ("jacobian", "parity", "mu_size", "mu_size_err", "ln_mu_size_err",
                 "mu_size_p16", "mu_size_p84", "mu_size_status"):
        tab[name] = size[name]
    tab["parity_snr"], tab["parity"] = determined_parity(
        size["parity"], size["ln_mu_size_err"],
        np.isin(np.asarray(size["mu_size_status"]), TESTABLE_STATUS), snr_threshold)
    for name in flux.colnames:
        if name != "ln_mu_flux_err":
            tab[name] = flux[name]

    mu_size = np.asarray(size["mu_size"], dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.asarray(tested_flux["mu_flux"], dtype=float) / mu_size
        ln_size_err = np.asarray(size["ln_mu_size_err"], dtype=float)
        ln_flux_err = np.asarray(tested_flux["ln_mu_flux_err"], dtype=float)
        ln_total = np.hypot(ln_flux_err, ln_size_err)
        snr = np.abs(np.log(ratio)) / ln_total
        rel_size_err = np.asarray(size["mu_size_err"]) / mu_size
        snr_paper = np.abs(ratio - 1.0) / (ratio * rel_size_err)
        size_dof = np.asarray(size["ln_mu_size_err_dof"], dtype=float)
        dof = (size_dof if snr_definition == "paper"
               else _snr_dof(ln_total, ln_size_err, size_dof))
    tab["ln_mu_size_err_dof"] = size_dof
    tab["duality_ratio"] = ratio
    tab["duality_ratio_err"] = ratio * ln_total
    tab["snr"] = snr
    tab["snr_paper"] = snr_paper
    profile = _profile_of(size) if snr_definition in _PROFILE_DEFINITIONS else None
    chosen = _chosen_snr(tab, size, tested_flux, snr_definition, profile)
    tested = (np.isfinite(chosen) & np.isin(np.asarray(size["mu_size_status"]), TESTABLE_STATUS)
              & (dof > 0))
    dof = np.where(tested, dof, np.nan)
    pval = np.where(tested, _t_p_value(np.where(tested, chosen, 0.0),
                                       np.where(tested, dof, np.inf)), np.nan)
    signif = np.where(tested, duality_significance(np.where(tested, chosen, 0.0),
                                                   np.where(tested, dof, np.inf)), np.nan)
    tab["snr_dof"] = dof
    tab["significance"] = signif
    tab["doubt"] = doubt
    if "flux_doubt" in tab.colnames:
        tab["flux_doubt"] = flux_doubt.astype(str)
    tab["tested"] = tested
    tab["p_value"] = pval
    tab["p_value_holm"] = holm_adjust(pval)
    tab["anomalous"] = tested & (signif > snr_threshold)
    joint_meta = {}
    if test == "joint":
        joint_meta = _joint_test(tab, theta2, tested_flux, sigma_pos, keep, snr_threshold,
                                 profile if snr_definition == "conservative" else None)

    tab.meta["bands"] = bands
    meta = {
        "test": test,
        **({"test_auto": why} if why else {}),
        "method": method,
        "sigma_pos": size.meta["sigma_pos"],
        "n_bootstrap": size.meta.get("n_bootstrap", 0),
        "snr_threshold": snr_threshold,
        "snr_definition": snr_definition,
        "n_flagged": int(np.count_nonzero(tab["anomalous"])),
    }
    if "reverse_map_rows" in size.meta:
        # rows of the kept pairs -> pair ids of the whole table
        rows = np.flatnonzero(keep)[np.asarray(size.meta["reverse_map_rows"], dtype=int)]
        meta["reverse_map_pairs"] = [int(i) for i in np.asarray(tab["pair_id"])[rows]]
    meta.update(joint_meta)
    meta.update(_family_summary(np.asarray(tab["p_value"], dtype=float), snr_threshold))
    tab.meta["duality"] = meta
    return tab


def _chosen_snr(tab, size, flux, snr_definition, profile=None):
    """The SNR ``snr_definition`` names, from the ``snr`` and ``snr_paper``
    columns of ``tab``; for "profile" and "conservative" (``profile`` the
    callable of :func:`_profile_of` on ``size``) it adds ``snr_profile`` and
    ``jacobian_cov`` to ``tab``."""
    if snr_definition not in _PROFILE_DEFINITIONS:
        return np.asarray(tab["snr" if snr_definition == "log" else "snr_paper"], dtype=float)
    tab["jacobian_cov"] = size["jacobian_cov"]
    prof = tab["snr_profile"] = profile(np.log(np.asarray(flux["mu_flux"], float)),
                                        np.asarray(flux["ln_mu_flux_err"], float))
    if snr_definition == "conservative":
        # flagged only where both the linearised and the profile SNR reject
        return np.fmin(np.asarray(tab["snr"], dtype=float), prof)
    return prof


def _profile_parts(size):
    """The determinants of the Jacobians (N,), the variance of ``ln mu_size``
    their covariances do not carry (the model and centre terms), and the
    whitened forms of :func:`lensdual._profile_kernels.whiten_all` (``q``,
    ``yh``, ``ok``), computed once for every target."""
    jac = np.ascontiguousarray(np.asarray(size["jacobian"], dtype=float).reshape(-1, 4))
    cov = np.ascontiguousarray(np.asarray(size["jacobian_cov"], dtype=float))
    ln_sd = np.asarray(size["ln_mu_size_err"], dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        det = jac[:, 0] * jac[:, 3] - jac[:, 1] * jac[:, 2]
        grad = np.column_stack([jac[:, 3], -jac[:, 2], -jac[:, 1], jac[:, 0]]) / det[:, None]
        var_jac = np.einsum("ni,nij,nj->n", grad, cov, grad)
        var_rest = np.where(np.isfinite(det), np.maximum(ln_sd * ln_sd - var_jac, 0.0), np.nan)
    n = det.size
    q, yh, ok = np.empty((n, 4)), np.empty((n, 4)), np.empty(n, dtype=bool)
    _profile_kernels.whiten_all(jac, cov, q, yh, ok)
    return det, var_rest, q, yh, ok


def _profile_rows(parts, ln_target, extra_sd, rows=None):
    """The profile SNR of the pairs ``rows`` (a boolean mask; all by default)
    for the targets ``ln_target`` with the extra errors ``extra_sd``; NaN
    elsewhere and where a pair has no estimate."""
    det, var_rest, q, yh, whitened = parts
    var = var_rest + np.asarray(extra_sd, dtype=float) ** 2
    ln_target = np.broadcast_to(np.asarray(ln_target, dtype=float), var.shape)
    ok = np.isfinite(var) & np.isfinite(ln_target) & whitened
    if rows is not None:
        ok &= rows
    out = np.full(var.shape, np.nan)
    res = np.empty(int(ok.sum()))
    _profile_kernels.profile_snr_whitened(
        np.ascontiguousarray(q[ok]), np.ascontiguousarray(yh[ok]), np.ones(res.size, dtype=bool),
        np.ascontiguousarray(det[ok]), np.ascontiguousarray(var[ok]),
        np.ascontiguousarray(ln_target[ok]), res)
    out[ok] = res
    return out


def _profile_of(size):
    """``profile(h, sd, rows)``: :func:`profile_snr` of ``size``'s Jacobians for the
    targets ``h`` with the extra errors ``sd``, on the pairs ``rows`` (the joint
    test's)."""
    parts = _profile_parts(size)

    def profile(ln_target, sd, rows=None):
        return _profile_rows(parts, ln_target, sd, rows)
    return profile


def profile_snr(size, ln_mu_flux, ln_flux_err):
    """The profile-likelihood duality SNR of each pair of a
    :func:`~lensdual.estimators.size_magnification` table (method
    ``"adaptive"``): the Jacobian's covariance ``jacobian_cov`` carries the
    part ``g^T C g`` of the variance of ``ln mu_size`` (``g`` the gradient of
    ``ln|det J|``), the rest of it and the flux ratio's variance enter in
    ``ln|det J|`` (:mod:`lensdual._profile_kernels`). NaN where the pair has
    no estimate."""
    return _profile_rows(_profile_parts(size), ln_mu_flux, ln_flux_err)


def check_test_settings(test, snr_definition, method, bands, n_pairs=None):
    """The test and SNR definition that ``test`` and ``snr_definition`` name for
    ``method`` and ``bands``, checked together.

    Parameters
    ----------
    test : {"auto", "geometric", "joint"}
        See :func:`resolve_test`.
    snr_definition : {"auto", "log", "paper", "profile", "conservative"}
        See :func:`resolve_snr_definition`.
    method : str
        The size-magnification estimator.
    bands : sequence of str
        The bands with flux ratios.
    n_pairs : int, optional
        The pairs with flux ratios (None: not known yet).

    Returns
    -------
    test, snr_definition : str
        Resolved.
    why : str
        Why ``"auto"`` ran the geometric test, in words; empty otherwise.

    Raises
    ------
    ValueError
        An unknown name; the joint test without the adaptive estimator, two
        bands or a log-type SNR; the profile or conservative SNR without the
        adaptive estimator.

    Examples
    --------
    >>> from lensdual.duality import check_test_settings
    >>> check_test_settings("auto", "auto", "quad2", ["F150W", "F200W"])
    ('geometric', 'log', 'the joint test needs the adaptive estimator, not quad2')
    """
    snr_definition = resolve_snr_definition(snr_definition, method)
    resolved = resolve_test(test, method, bands, snr_definition, n_pairs)
    if resolved == "joint":
        _check_joint_input(bands, snr_definition, method)
    if snr_definition in _PROFILE_DEFINITIONS and method != "adaptive":
        raise ValueError(f"snr_definition={snr_definition!r} needs method 'adaptive' (the "
                         f"covariance of its Jacobian), got method {method!r}")
    why = (_why_not_joint(method, bands, snr_definition, n_pairs)
           if test == "auto" and resolved == "geometric" else "")
    return resolved, snr_definition, why


def _check_joint_input(bands, snr_definition, method):
    if method != "adaptive":
        raise ValueError(f"test='joint' needs method='adaptive', got {method!r}: the flux "
                         "field is predicted only where the adaptive fits found the lens map "
                         "resolved, and only its errors include the estimator's own")
    if len(bands) < 2:
        raise ValueError(
            f"test='joint' needs at least two bands, got {list(bands)}: with one band the "
            "chromatic check cannot keep mis-paired sources out of the neighbours' flux "
            "field; use test='geometric'")
    if snr_definition not in LOG_SNR_DEFINITIONS:
        raise ValueError(f"test='joint' uses snr_definition 'log' or 'conservative', got "
                         f"{snr_definition!r} (the paper's definition has no flux error to "
                         "combine)")


def _ws_dof(total_var, parts):
    """Welch-Satterthwaite degrees of freedom of ``total_var``, a sum of known terms
    and the estimated ``(variance, dof)`` terms of ``parts`` (infinite dof: known)."""
    den = np.zeros_like(total_var)
    for var, dof in parts:
        est = np.isfinite(dof) & (dof > 0)
        den = den + np.where(est, var**2 / np.where(est, dof, 1.0), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den > 0, total_var**2 / np.where(den > 0, den, 1.0), np.inf)


def _significance_of(snr, dof, ok):
    out = np.full(snr.shape, np.nan)
    out[ok] = duality_significance(snr[ok], dof[ok])
    return out


class _JointPass(NamedTuple):
    """One pass of the joint test, per pair (see :func:`_joint_pass`)."""

    snr: np.ndarray
    dof: np.ndarray
    significance: np.ndarray
    tested: np.ndarray
    consistency: np.ndarray
    fails: np.ndarray
    basis: np.ndarray
    outlier: np.ndarray
    prediction: np.ndarray  # ln mu predicted by the geometry and the field combined
    prediction_var: np.ndarray


def _joint_profile_snr(profile, ln_flux, ln_flux_err, f, f_var, g_ok, f_ok):
    """The profile-likelihood SNR of the joint test (NaN where the geometry is
    not tested).

    ``profile(h, sd, rows)`` is :func:`profile_snr` of the pairs' Jacobians
    for targets ``h`` with extra errors ``sd`` on the pairs ``rows``, whose
    square is the profile statistic ``P(h, sd^2)``. With the geometry alone the SNR is
    ``sqrt(P(R, v_R))``; with the field ``f`` (variance ``v_f``) too, the
    likelihood ratio of the flux ratio tied to the common ``ln mu`` against
    free: ``(R - f)^2 / (v_R + v_f) + P(w, v_c) - P(f, v_f)``, ``w`` and
    ``v_c`` the inverse-variance mean of ``R`` and ``f`` and its variance.
    """
    out = np.full(ln_flux.shape, np.nan)
    geo_only = g_ok & ~f_ok
    if geo_only.any():
        out[geo_only] = profile(ln_flux, ln_flux_err, geo_only)[geo_only]
    both = g_ok & f_ok
    if both.any():
        with np.errstate(invalid="ignore", divide="ignore"):
            v_r, v_f = ln_flux_err**2, np.where(both, f_var, 1.0)
            v_c = 1.0 / (1.0 / v_r + 1.0 / v_f)
            f_b = np.where(both, f, 0.0)
            w = (ln_flux / v_r + f_b / v_f) * v_c
            t2 = ((ln_flux - f) ** 2 / (v_r + v_f) + profile(w, np.sqrt(v_c), both) ** 2
                  - profile(f_b, np.sqrt(v_f), both) ** 2)
        out[both] = np.sqrt(np.maximum(t2, 0.0))[both]
    return out


def _joint_pass(ln_flux, ln_flux_err, geo, field, snr_threshold, profile=None):
    """One pass of the joint test.

    With ``profile`` (the callable of :func:`_joint_profile_snr`), the SNR
    where the geometry is tested is the smaller of the linearised one and the
    profile-likelihood one (``snr_definition="conservative"``).

    Returns a `_JointPass`. ``outlier`` marks the pairs left out of the others' flux field
    in the next pass: the flagged pairs, and those whose flux ratio is off
    their own flux-field prediction beyond ``snr_threshold`` whether the
    smooth field fails there or not. A pair that disagrees with the geometry
    alone, where the smooth field fails, is no outlier of the field.
    """
    g, g_var, g_dof, g_ok = geo
    f, f_var, f_ok = field
    both = g_ok & f_ok
    with np.errstate(invalid="ignore", divide="ignore"):
        diff_var = g_var + f_var
        cons_snr = np.abs(g - f) / np.sqrt(diff_var)
        cons_dof = _ws_dof(diff_var, [(g_var, g_dof)])
        consistency = _significance_of(cons_snr, cons_dof, both & np.isfinite(cons_snr))
        fails = both & (consistency > snr_threshold)
        w_g = np.where(g_ok, 1.0 / g_var, 0.0)
        w_f = np.where(f_ok, 1.0 / f_var, 0.0)
        pred_var = 1.0 / (w_g + w_f)
        pred = (np.where(g_ok, g, 0.0) * w_g + np.where(f_ok, f, 0.0) * w_f) * pred_var
        total_var = ln_flux_err**2 + pred_var
        # the geometric share of the predicted variance carries its dof
        g_share = np.where(g_ok, pred_var**2 * w_g, 0.0)
        dof = _ws_dof(total_var, [(g_share, g_dof)])
        snr = np.abs(ln_flux - pred) / np.sqrt(total_var)
        if profile is not None:
            snr = np.where(g_ok, np.fmin(snr, _joint_profile_snr(
                profile, ln_flux, ln_flux_err, f, f_var, g_ok, f_ok)), snr)
        off_field = np.abs(ln_flux - f) / np.sqrt(ln_flux_err**2 + f_var)
    tested = (g_ok | f_ok) & ~fails & np.isfinite(snr) & (dof > 0)
    signif = _significance_of(snr, dof, tested)
    basis = np.where(both, "geometry+field", np.where(f_ok, "field",
                                                     np.where(g_ok, "geometry", "")))
    outlier = (tested & (signif > snr_threshold)) | (f_ok & (off_field > snr_threshold))
    return _JointPass(snr, dof, signif, tested, consistency, fails, basis, outlier, pred,
                      pred_var)


def _joint_passes(pos2, ln_flux, ln_flux_err, sig2, geo, keep, resolved, snr_threshold,
                  profile=None):
    """The joint test on arrays, pass by pass until the left-out pairs settle.

    ``pos2`` (N, 2) and ``sig2`` (N,) in arcsec; ``geo`` as in :func:`_joint_pass`;
    ``keep`` the pairs that may inform the field; ``resolved`` where the
    adaptive fits passed; ``profile`` as in :func:`_joint_pass`. Returns
    ``(result, field, flagged)``: the last pass's
    `_JointPass`, its flux field (:func:`lensdual.flux_field.field_arrays`)
    and the pairs left out of the others' field.
    """
    from .flux_field import field_arrays

    usable = keep & np.isfinite(ln_flux) & np.isfinite(ln_flux_err)
    flagged = np.zeros(ln_flux.size, dtype=bool)
    for _ in range(_JOINT_MAX_PASSES):
        field = field_arrays(pos2, ln_flux, ln_flux_err, sig2, usable & ~flagged, resolved)
        f_ok = (field.status == "ok") & keep
        result = _joint_pass(ln_flux, ln_flux_err, geo, (field.value, field.var, f_ok),
                             snr_threshold, profile)
        if np.array_equal(result.outlier, flagged):
            break
        flagged = result.outlier
    return result, field, flagged


def _joint_test(tab, theta2, flux, sigma_pos, keep, snr_threshold, profile=None):
    """Replace the test columns of ``tab`` by the joint test's (see check_duality);
    ``profile`` as in :func:`_joint_pass`."""
    from .estimators.core import as_sigma

    n = len(tab)
    ln_flux = np.log(np.asarray(flux["mu_flux"], dtype=float))
    ln_flux_err = np.asarray(flux["ln_mu_flux_err"], dtype=float)
    geo_tested = np.asarray(tab["tested"], dtype=bool)
    with np.errstate(invalid="ignore", divide="ignore"):
        geo = (np.log(np.asarray(tab["mu_size"], dtype=float)),
               np.asarray(tab["ln_mu_size_err"], dtype=float) ** 2,
               np.asarray(tab["ln_mu_size_err_dof"], dtype=float), geo_tested)
    # the L2 position errors of the kept pairs (a doubtful pair's may be unknown)
    sig2 = np.full(n, np.nan)
    sig2[keep] = as_sigma(_subset_sigma(sigma_pos, keep), int(keep.sum()))[1]
    result, field, flagged = _joint_passes(
        np.asarray(theta2.to_value(u.arcsec), dtype=float), ln_flux, ln_flux_err,
        sig2, geo, keep, np.asarray(tab["mu_size_status"]) == "ok", snr_threshold, profile)
    snr, dof, signif, tested = result.snr, result.dof, result.significance, result.tested
    tab["significance_geometric"] = tab["significance"]
    tab["snr_dof_geometric"] = tab["snr_dof"]
    tab["anomalous_geometric"] = tab["anomalous"]
    tab["ln_mu_field"] = field.value
    tab["ln_mu_field_err"] = np.sqrt(field.var)
    tab["field_status"] = field.status
    tab["field_n"] = field.n_used
    tab["field_dropped"] = field.n_dropped
    tab["field_consistency"] = result.consistency
    tab["smooth_field_fails"] = result.fails
    tab["joint_basis"] = result.basis
    # the prediction the flux ratio is tested against, and its error (the flux
    # ratio's own error not included): what a sensitivity map or an abundance
    # limit of the joint test reads
    tab["ln_mu_predicted"] = np.where(tested, result.prediction, np.nan)
    tab["ln_mu_predicted_err"] = np.where(tested, np.sqrt(result.prediction_var), np.nan)
    tab["snr"] = snr
    tab["snr_dof"] = np.where(tested, dof, np.nan)
    tab["significance"] = signif
    tab["tested"] = tested
    pval = np.full(n, np.nan)
    pval[tested] = _t_p_value(snr[tested], dof[tested])
    tab["p_value"] = pval
    tab["p_value_holm"] = holm_adjust(pval)
    tab["anomalous"] = tested & (signif > snr_threshold)
    ids = np.asarray(tab["pair_id"])
    return {"field_model_sd": float(np.sqrt(field.model_var)),
            "field_excluded_pairs": [int(i) for i in ids[flagged]]}


# ---------------------------------------------------------------------------
# Null calibration on the user's own constellation
# ---------------------------------------------------------------------------

# Realisations per random block: each block has its own seed, so results do
# not depend on how blocks are grouped into tasks.
_NULL_BLOCK = 50
_NULL_MIN_REALISATIONS = 100
# Below this many residual degrees of freedom per coordinate the null map
# interpolates the pairs, so it holds their position noise: a warning, and the
# verdict calls the null's rates uncertain.
_NULL_MAP_MIN_RESIDUAL_DOF = 1.0

#: The smooth map the null takes as the truth (see :mod:`lensdual._null_map`).
_smooth_map = spline_map


def _null_block(task):
    """SNRs of one block of null realisations (module level: picklable)."""
    (block, entropy, size, t1, t2, sigma, mu_true, ln_flux_err, wp, joint, conservative) = task
    from .estimators.core import adaptive_batch

    rng = np.random.default_rng(np.random.SeedSequence(entropy, spawn_key=(block,)))
    n = t1.shape[0]
    noise1 = rng.standard_normal((size, n, 2)) * sigma[0][None, :, None]
    noise2 = rng.standard_normal((size, n, 2)) * sigma[1][None, :, None]
    ln_flux = np.log(mu_true)[None, :] + ln_flux_err[None, :] * rng.standard_normal((size, n))
    if joint is not None:
        return _null_block_joint(t1, t2, noise1, noise2, sigma, wp, ln_flux, ln_flux_err,
                                 *joint, conservative)
    mu_size, ln_sd, ok, size_dof, *jac = adaptive_batch(t1, t2, noise1, noise2, sigma, wp,
                                                         with_jacobian=conservative)
    with np.errstate(divide="ignore", invalid="ignore"):
        total = np.hypot(ln_flux_err[None, :], ln_sd)
        snr = np.abs(ln_flux - np.log(mu_size)) / total
        if conservative:
            prof = profile_snr(_batch_size_table(*jac, ln_sd), ln_flux.ravel(),
                               np.broadcast_to(ln_flux_err, ln_flux.shape).ravel())
            snr = np.fmin(snr, prof.reshape(snr.shape))
        dof = _snr_dof(total, ln_sd, size_dof)
        ok = ok & np.isfinite(snr) & (dof > 0)
        signif = duality_significance(np.where(ok, snr, 0.0), np.where(ok, dof, np.inf))
    return np.where(ok, signif, np.nan)


def _batch_size_table(jac, cov, ln_sd):
    """The columns :func:`profile_snr` reads, flattened over realisations and pairs."""
    return {"jacobian": jac.reshape(-1, 2, 2), "jacobian_cov": cov.reshape(-1, 4, 4),
            "ln_mu_size_err": ln_sd.ravel()}


def _null_block_joint(t1, t2, noise1, noise2, sigma, wp, ln_flux, ln_flux_err, keep,
                      snr_threshold, conservative=False):
    """Joint-test significances of one block of null realisations."""
    from .estimators.core import adaptive_batch

    mu_size, ln_sd, ok, size_dof, fit_ok, *jac = adaptive_batch(
        t1, t2, noise1, noise2, sigma, wp, with_ok=True, with_jacobian=conservative)
    out = np.full(ln_flux.shape, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        ln_size = np.log(mu_size)
        g_ok = ok & np.isfinite(ln_size) & np.isfinite(ln_sd) & ~(size_dof <= 0)
    for b in range(ln_flux.shape[0]):
        geo = (ln_size[b], ln_sd[b] ** 2, size_dof[b], g_ok[b])
        profile = (_profile_of(_batch_size_table(jac[0][b], jac[1][b], ln_sd[b]))
                   if conservative else None)
        result, _, _ = _joint_passes(t2 + noise2[b], ln_flux[b], ln_flux_err, sigma[1], geo,
                                     keep, fit_ok[b], snr_threshold, profile)
        out[b] = np.where(result.tested, result.significance, np.nan)
    return out


def _seed_entropy(seed):
    if isinstance(seed, np.random.Generator):
        return int(seed.integers(2**63))
    if seed is None:
        return int(np.random.SeedSequence().entropy)
    if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and seed >= 0:
        return int(seed)
    raise TypeError(f"seed must be None, a non-negative int or a numpy Generator, got {seed!r}")


def null_calibration(pairs, *, sigma_pos, n_realisations=1000,
                     snr_threshold=DEFAULT_SNR_THRESHOLD, seed=None, client=None, chunk_size=4,
                     weight_power=2, test=DEFAULT_TEST, snr_definition=DEFAULT_SNR_DEFINITION):
    """Empirical false-alarm rate and p-values of the duality test on a null like the data.

    A smooth, model-independent map from arc L2 to arc L1 is fitted to the
    pairs: a polyharmonic smoothing spline (kernel ``-r^5``, quadratic
    polynomial part; as smooth as the estimator's local cubic fits assume)
    weighted by the position errors, whose smoothing minimises the unbiased
    risk estimate of the fitted positions (no threshold: the errors are
    known), so that it bends as much as the pairs show and no more. Each null
    realisation takes the measured L2 positions as the truth, maps them
    through it, sets the flux ratios to the map's exact ``|det J|`` (duality
    holds: no sub-halo), adds Gaussian
    noise of the user's ``sigma_pos`` to every position and of the user's
    flux-ratio errors to every ``ln mu_flux``, and runs the same adaptive
    estimator and SNR as :func:`check_duality`. The observed SNRs are then
    ranked against this null.

    Parameters
    ----------
    pairs : `~astropy.table.Table`
        The pairs table, as for :func:`check_duality` (positions and fluxes).
    sigma_pos : `~astropy.units.Quantity`
        Position errors, as for :func:`check_duality` (scalar, (N,) or (2, N));
        must be > 0.
    n_realisations : int
        Null realisations (at least 100; default 1000).
    snr_threshold : float
        Threshold of the false-alarm rates (default 3).
    seed : int, `numpy.random.Generator` or None
        Seed; realisations come in blocks of 50, each seeded from it and its
        block number, so that results do not depend on ``client`` or
        ``chunk_size``.
    client : `dask.distributed.Client` or `concurrent.futures.Executor`, optional
        Where to run the blocks (default: here, in threads over the cores
        this process may use, up to 8: the estimator's kernel releases the
        GIL).
    chunk_size : int
        Blocks of 50 realisations per task of ``client`` (default 4; one
        block per task in the default threads).
    weight_power : float
        Weight power of the Quad pilot, see
        :func:`~lensdual.estimators.relative_jacobian`.
    test : {"auto", "geometric", "joint"}
        The test to calibrate, as in :func:`check_duality` (default
        ``"auto"``: the joint test where it applies, :func:`resolve_test`). With ``"joint"``
        each realisation also predicts every pair's ``ln mu`` from the other
        pairs' noisy flux ratios, at the noisy L2 positions, with the passes
        of :func:`check_duality`; the pairs that are doubtful in ``pairs``
        inform no prediction. The null's field is the smooth map's
        ``ln |det J|``: as smooth as the map (see Notes).
    snr_definition : {"auto", "log", "conservative"}
        The SNR of the observed and the null significances, as in
        :func:`check_duality` (default ``"auto"``: ``"conservative"``).

    Returns
    -------
    table : `~astropy.table.QTable`
        One row per pair: ``pair_id``, ``snr`` and ``significance``
        (observed, as :func:`check_duality`), ``tested``, ``p_value`` (as
        :func:`check_duality`), ``p_value_empirical`` (``(1 + #null
        significance >= significance) / (1 + #null)`` of that pair),
        ``false_alarm_rate`` (fraction of that pair's null realisations
        above the threshold) and ``null_snr`` (its ``n_realisations`` null
        significances, the Gaussian-equivalent SNRs that the threshold is
        applied to; NaN where untested). ``meta`` holds
        ``false_alarm_rate`` (over all pairs), ``nominal_false_alarm_rate``,
        ``expected_false_flags`` (mean number of flags per null
        realisation), ``p_any_false_flag`` (fraction of null realisations
        with at least one flag), ``family_wise_p_empirical`` (fraction with a
        largest SNR at least the observed largest), the null map's ``map``
        (in words), ``map_dof`` (its effective degrees of freedom per
        coordinate: 6 for a quadratic map, the number of pairs for one that
        interpolates them), ``map_chi2_dof`` and ``map_interpolates`` (fewer
        than one residual degree of freedom per coordinate, with a warning),
        and the settings.

    Raises
    ------
    ValueError
        ``n_realisations`` < 100, fewer than 7 pairs, non-positive
        ``sigma_pos`` or flux errors, and the bad inputs of
        :func:`check_duality`.
    TypeError
        ``client`` without a ``map`` method; a bad ``seed``.

    Warns
    -----
    LensdualWarning
        The null map interpolates the pairs (``map_interpolates``): the
        constellation does not sample the map finely enough to tell its
        bending from the position noise, or ``sigma_pos`` is too small; the
        null's map then holds that noise, and its rates are uncertain.

    Notes
    -----
    The null's map is the spline, not the lens, and between the pairs the two
    differ. Where few pairs sample a steep map, the null flags more often
    than the real constellation (Abell 370 on the calibration page). On
    galaxy-scale folds sampled by 8-12 pairs, more clean pairs get small
    empirical p-values than their level says, with the warning only where the
    spline interpolates the pairs. The calibration page has the measurements.

    Examples
    --------
    The pairs of :func:`check_duality`'s example (pair 4 twice too bright on
    arc L1), ranked against 100 null realisations:

    >>> import numpy as np
    >>> import astropy.units as u
    >>> from astropy.table import QTable
    >>> rng = np.random.default_rng(1)
    >>> theta2 = rng.uniform(-1, 1, (8, 2))
    >>> theta1 = theta2 @ np.array([[1.5, 0.3], [0.1, -0.8]]).T  # mu_size = 1.23
    >>> flux2 = np.full(8, 100.0)
    >>> flux1 = 1.23 * flux2
    >>> flux1[3] *= 2  # pair 4: twice too bright in L1
    >>> pairs = QTable({"x1": theta1[:, 0] * u.arcsec, "y1": theta1[:, 1] * u.arcsec,
    ...                 "x2": theta2[:, 0] * u.arcsec, "y2": theta2[:, 1] * u.arcsec,
    ...                 "flux1_F150W": flux1, "flux2_F150W": flux2,
    ...                 "flux_err1_F150W": 0.02 * flux1, "flux_err2_F150W": 0.02 * flux2})
    >>> from lensdual.duality import null_calibration
    >>> null = null_calibration(pairs, sigma_pos=0.005 * u.arcsec, n_realisations=100, seed=0)
    >>> null["null_snr"].shape
    (8, 100)
    >>> round(float(null["p_value_empirical"][3]), 4)  # no null SNR as large: 1 / 101
    0.0099
    >>> round(null.meta["map_dof"], 1)  # an affine map: the polynomial part's 6
    6.0
    """
    from .estimators.core import as_sigma

    n_real = as_int(n_realisations, "n_realisations", minimum=1)
    if n_real < _NULL_MIN_REALISATIONS:
        raise ValueError(f"n_realisations must be >= {_NULL_MIN_REALISATIONS} for a null "
                         f"calibration (p-values of 1/n), got {n_real}")
    chunk = as_int(chunk_size, "chunk_size", minimum=1)
    entropy = _seed_entropy(seed)
    check_client(client)
    if snr_definition not in ("auto",) + LOG_SNR_DEFINITIONS:
        raise ValueError(f"null_calibration takes snr_definition 'auto', 'log' or "
                         f"'conservative', got {snr_definition!r}")
    observed = check_duality(pairs, "adaptive", sigma_pos=sigma_pos,
                             snr_threshold=snr_threshold, weight_power=weight_power, test=test,
                             snr_definition=snr_definition)
    test = observed.meta["duality"]["test"]  # "auto" resolved
    snr_definition = observed.meta["duality"]["snr_definition"]
    # the null is simulated on the pairs check_duality kept (the doubtful ones, whose
    # positions or errors may be unknown, inform no estimate there either)
    keep = np.asarray(observed["doubt"]) == ""
    n_all = keep.size
    theta1, theta2 = _positions(observed)
    t1 = np.ascontiguousarray(theta1.to_value(u.arcsec)[keep])
    t2 = np.ascontiguousarray(theta2.to_value(u.arcsec)[keep])
    n = t1.shape[0]
    sigma = as_sigma(_subset_sigma(sigma_pos, keep), n, positive=True)
    # a doubtful flux ratio is untested in the null too, as in check_duality
    flux = _without_doubtful_fluxes(flux_ratios(pairs), doubts_of(pairs, "flux_doubt"))
    ln_flux_err = np.asarray(flux["ln_mu_flux_err"], dtype=float)[keep]
    ln_flux_err = np.where(np.isfinite(ln_flux_err), ln_flux_err, np.inf)

    null_map = _smooth_map(t1, t2, sigma)
    mapped, jac, chi2_dof = null_map.mapped, null_map.jacobian, null_map.chi2_dof
    interpolates = bool(n - null_map.dof < _NULL_MAP_MIN_RESIDUAL_DOF)
    if interpolates:
        warnings.warn(
            f"the null map ({null_map.description}) interpolates the pairs: the "
            "constellation does not sample the map finely enough to tell its bending from "
            "the position noise (or sigma_pos is too small), so the null holds that noise "
            "and its empirical false-alarm rates are uncertain",
            LensdualWarning,
            stacklevel=2,
        )
    mu_true = np.abs(jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0])
    mapped = np.ascontiguousarray(mapped)
    n_blocks = -(-n_real // _NULL_BLOCK)
    sizes = [min(_NULL_BLOCK, n_real - b * _NULL_BLOCK) for b in range(n_blocks)]
    joint = (np.ones(n, dtype=bool), float(snr_threshold)) if test == "joint" else None
    args = [(b, entropy, sizes[b], mapped, t2, sigma, mu_true, ln_flux_err, float(weight_power),
             joint, snr_definition == "conservative") for b in range(n_blocks)]
    if client is None:  # one block per task, in threads over the cores we may use
        with ThreadPoolExecutor(min(_available_threads(), n_blocks)) as pool:
            parts = run_tasks(_null_tasks, [[a] for a in args], pool)
    else:
        tasks = [args[i:i + chunk] for i in range(0, n_blocks, chunk)]
        parts = run_tasks(_null_tasks, tasks, client)
    null = np.full((n_real, n_all), np.nan)  # (n_real, N): NaN for the doubtful pairs
    null[:, keep] = np.vstack([blk for part in parts for blk in part])

    snr = np.asarray(observed["significance"], dtype=float)
    tested = np.asarray(observed["tested"], dtype=bool)
    valid = np.isfinite(null)
    n_valid = valid.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        exceed = (np.where(valid, null, -np.inf) >= snr[None, :]).sum(axis=0)
        p_emp = np.where(tested, (1.0 + exceed) / (1.0 + n_valid), np.nan)
        above = np.where(valid, null, -np.inf) > snr_threshold
        far_pair = np.where(n_valid > 0, above.sum(axis=0) / n_valid, np.nan)
    flags = above.sum(axis=1)
    obs_max = np.nanmax(np.where(tested, snr, np.nan)) if tested.any() else np.nan
    null_max = np.nanmax(np.where(valid, null, -np.inf), axis=1)

    out = QTable()
    out["pair_id"] = observed["pair_id"]
    out["snr"] = observed["snr"]
    out["significance"] = snr
    out["tested"] = tested
    out["p_value"] = observed["p_value"]
    out["p_value_empirical"] = p_emp
    out["false_alarm_rate"] = far_pair
    out["null_snr"] = null.T
    out.meta.update({
        "n_realisations": n_real,
        "snr_threshold": float(snr_threshold),
        "false_alarm_rate": float(above.sum() / max(valid.sum(), 1)),
        "nominal_false_alarm_rate": float(gaussian_p_value(snr_threshold)),
        "expected_false_flags": float(flags.mean()),
        "p_any_false_flag": float((flags > 0).mean()),
        "family_wise_p_empirical": (float((1 + (null_max >= obs_max).sum()) / (1 + n_real))
                                    if np.isfinite(obs_max) else np.nan),
        "map": null_map.description,
        "map_dof": float(null_map.dof),
        "map_chi2_dof": float(chi2_dof),
        "map_interpolates": interpolates,
        "seed_entropy": entropy,
        "method": "adaptive",
        "test": test,
        "snr_definition": snr_definition,
    })
    return out


def _null_tasks(blocks):
    return [_null_block(b) for b in blocks]

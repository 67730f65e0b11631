"""Size magnification of a knot constellation beside lens models' magnification ratios.

A position-only constellation (e.g. from :func:`lensdual.pairing.pairs_from_knots`)
has no flux ratios, but its size magnification is still a model-independent
measurement of ``|mu(L1) / mu(L2)|`` at every knot. :func:`compare_size_with_models`
puts it beside the ratios that one or several lens models predict at the same
knots, with the errors of both sides, and :func:`plot_size_vs_model` draws
the comparison.

The error of a model's ratio here is the one its inputs give it: the
catalogued positions are uncertain by ``sigma_pos``, and near a critical
curve ``ln |mu|`` changes fast, so the model ratio at the *true* knot positions
differs from the one at the catalogued positions by
``|grad ln|mu_model|| sigma_pos`` (finite differences, both images). A
`~lensdual.parametric.ParametricFit` adds its parameter uncertainty. A
published best-fit Lenstool model carries no parameter uncertainty of its own;
comparing several models shows the systematic one.
"""

from collections.abc import Mapping

import numpy as np
from astropy import units as u
from astropy.table import QTable, Table

from .._pairs_table import arc_xy
from .._validation import as_angle_scalar, as_real
from ..duality import DEFAULT_SNR_THRESHOLD
from ..visualization._parametric import plot_size_vs_model

__all__ = ["compare_size_with_models", "plot_size_vs_model"]

#: Finite-difference step (arcsec) of the gradient of ln |mu_model|.
_GRAD_STEP = 0.01


def _models(models):
    from .fitting import ParametricFit
    from .lenstool import LenstoolModel

    if isinstance(models, (LenstoolModel, ParametricFit)):
        models = [models]
    if isinstance(models, Mapping):
        items = [(str(k), v) for k, v in models.items()]
    else:
        items = []
        for k, m in enumerate(models, start=1):
            name = m.path.parent.name if isinstance(m, LenstoolModel) else f"fit{k}"
            items.append((name or f"model{k}", m))
    if not items:
        raise ValueError("models must hold at least one model")
    for name, m in items:
        if not isinstance(m, (LenstoolModel, ParametricFit)):
            raise TypeError(f"model {name!r} must be a LenstoolModel or a ParametricFit, got "
                            f"{type(m).__name__}")
    items = [("".join(c if c.isalnum() else "_" for c in n), m) for n, m in items]
    names = [n for n, _ in items]
    if len(set(names)) != len(names):
        raise ValueError(f"model names repeat: {names}; pass a dict {{name: model}}")
    return items


def _ln_mu(lens, xy):
    """ln |mu| at (N, 2) positions and its gradient norm (finite differences)."""
    h = _GRAD_STEP
    pts = np.concatenate([xy, xy + [h, 0], xy - [h, 0], xy + [0, h], xy - [0, h]])
    with np.errstate(divide="ignore"):
        mu = np.asarray(lens.magnification(pts[:, 0], pts[:, 1]), float)
        ln = np.log(np.abs(mu)).reshape(5, len(xy))
    grad = np.hypot((ln[1] - ln[2]) / (2 * h), (ln[3] - ln[4]) / (2 * h))
    return mu[:len(xy)], grad


def _model_ratio(model, tab, z_source, sigma):
    """(mu1, mu2, ratio, ln error) of one model at the pairs' positions."""
    from .fitting import ParametricFit

    if isinstance(model, ParametricFit):
        t1, t2 = arc_xy(tab, 1), arc_xy(tab, 2)
        pred = model.magnification_ratio(t1 * u.arcsec, t2 * u.arcsec)
        lens = _KwargsModel(model.lens_model, model.kwargs_lens)
        with np.errstate(all="ignore"):
            ln_fit = 0.5 * (np.log(np.asarray(pred["mu_model_p84"], float))
                            - np.log(np.asarray(pred["mu_model_p16"], float)))
    else:
        if "sky1" not in tab.colnames or "sky2" not in tab.colnames:
            raise ValueError("comparing with a Lenstool model needs the sky1 and sky2 columns "
                             "of the pairs table (pairs_from_knots gives them)")
        if z_source is None:
            raise ValueError("z_source is required to compare with a Lenstool model (or a "
                             "pairs table with meta['z_source'])")
        t1 = model.to_model_frame(tab["sky1"]).to_value(u.arcsec)
        t2 = model.to_model_frame(tab["sky2"]).to_value(u.arcsec)
        lens = model.lens_model(z_source)
        ln_fit = 0.0
    mu1, g1 = _ln_mu(lens, t1)
    mu2, g2 = _ln_mu(lens, t2)
    with np.errstate(all="ignore"):
        ratio = np.abs(mu1 / mu2)
    ln_err = np.sqrt(ln_fit**2 + (sigma * g1) ** 2 + (sigma * g2) ** 2)
    return mu1, mu2, ratio, ln_err


class _KwargsModel:
    """A lenstronomy LensModel with its kwargs bound (magnification(x, y))."""

    def __init__(self, lens_model, kwargs):
        self._lm, self._kw = lens_model, kwargs

    def magnification(self, x, y):
        return self._lm.magnification(x, y, self._kw)


def compare_size_with_models(pairs, models, *, sigma_pos, z_source=None, method="adaptive",
                             snr_threshold=DEFAULT_SNR_THRESHOLD):
    r"""Size magnification per pair beside one or several models' magnification ratios.

    Parameters
    ----------
    pairs : `~astropy.table.Table`
        A pairs table (:ref:`pairs-table`); fluxes are not needed. For a
        Lenstool model it needs ``sky1`` and ``sky2`` (as made by
        :func:`~lensdual.pairing.pairs_from_knots`), for a
        `~lensdual.parametric.ParametricFit` positions in the fit's frame.
    models : `LenstoolModel`, `ParametricFit`, sequence or dict
        The models; a dict gives them names (default: the folder of a
        Lenstool file, ``fit1``, ...).
    sigma_pos : `~astropy.units.Quantity`
        Position error per coordinate of both arcs (e.g. from
        :func:`~lensdual.estimators.estimate_sigma_pos`). It sets the error
        of ``mu_size`` and the position part of each model's error.
    z_source : float, optional
        Source redshift for Lenstool models (default ``pairs.meta['z_source']``).
    method : str
        Size-magnification estimator (default ``"adaptive"``, see
        :func:`~lensdual.estimators.size_magnification`).
    snr_threshold : float
        A pair disagrees with a model when :math:`|\ln(\mu_{\rm size} /
        \mu_{\rm model})| / \sqrt{\sigma_{\ln\,\rm size}^2 +
        \sigma_{\ln\,\rm model}^2}` exceeds it (default 3).

    Returns
    -------
    table : `~astropy.table.QTable`
        ``pair_id`` (and ``knot``, ``id1``, ``id2`` when present),
        ``mu_size``, ``mu_size_err``, ``ln_mu_size_err``, ``mu_size_status``,
        ``parity_snr`` (the significance of the sign of ``det J``,
        ``1 / ln_mu_size_err``; NaN where untestable), ``parity`` (that sign,
        0 where it is undetermined: untestable, or ``parity_snr`` below
        ``snr_threshold``), then for each model ``<name>``: ``mu_<name>``
        (the ratio ``|mu1 / mu2|``), ``ln_mu_<name>_err``, ``parity_<name>``
        (sign of ``mu1 mu2``), ``snr_<name>`` and ``disagree_<name>``: the
        SNR beyond ``snr_threshold``, or a determined parity opposite to the
        model's (False where the pair is untestable or the SNR is NaN and
        the parity undetermined). ``meta`` holds ``models``, ``sigma_pos``,
        ``snr_threshold`` and ``method``.

    Examples
    --------
    See the MACS J1149 worked example in the documentation ("Knot
    constellations of real clusters").
    """
    from .._pairs_table import positions as _positions
    from ..estimators import TESTABLE_STATUS, size_magnification
    from ..estimators.core import determined_parity

    if not isinstance(pairs, Table):
        raise TypeError(f"pairs must be an astropy Table, got {type(pairs).__name__}")
    tab = QTable(pairs, copy=False)
    items = _models(models)
    sigma = as_angle_scalar(sigma_pos, "sigma_pos", allow_zero=False)
    snr_threshold = as_real(snr_threshold, "snr_threshold", minimum=0.0)
    if z_source is None:
        z_source = tab.meta.get("z_source")
    if z_source is not None and not np.isfinite(z_source):
        z_source = None
    theta1, theta2 = _positions(tab)
    size = size_magnification(theta1, theta2, method=method, sigma_pos=sigma * u.arcsec)
    out = QTable()
    out["pair_id"] = (np.asarray(tab["pair_id"]) if "pair_id" in tab.colnames
                      else np.arange(1, len(tab) + 1))
    for c in ("knot", "id1", "id2"):
        if c in tab.colnames:
            out[c] = tab[c]
    out["mu_size"] = np.asarray(size["mu_size"], float)
    out["mu_size_err"] = np.asarray(size["mu_size_err"], float)
    if "ln_mu_size_err" in size.colnames:
        ln_size = np.asarray(size["ln_mu_size_err"], float)
    else:
        with np.errstate(all="ignore"):
            ln_size = out["mu_size_err"] / out["mu_size"]
    out["ln_mu_size_err"] = ln_size
    status = (np.asarray(size["mu_size_status"]) if "mu_size_status" in size.colnames
              else np.where(np.isfinite(out["mu_size"]), "ok", "failed"))
    out["mu_size_status"] = status
    testable = np.isin(status, TESTABLE_STATUS)
    out["parity_snr"], out["parity"] = determined_parity(size["parity"], ln_size, testable,
                                                         snr_threshold)
    determined = out["parity"] != 0
    for name, model in items:
        mu1, mu2, ratio, ln_model = _model_ratio(model, tab, z_source, sigma)
        out[f"mu_{name}"] = ratio
        out[f"ln_mu_{name}_err"] = ln_model
        out[f"parity_{name}"] = np.sign(mu1 * mu2).astype(int)
        with np.errstate(all="ignore"):
            snr = np.abs(np.log(out["mu_size"] / ratio)) / np.hypot(ln_size, ln_model)
        out[f"snr_{name}"] = snr
        flip = determined & (out[f"parity_{name}"] != 0) & (out["parity"] != out[f"parity_{name}"])
        out[f"disagree_{name}"] = (testable & np.isfinite(snr) & (snr > snr_threshold)) | flip
    out.meta.update(models=[n for n, _ in items], sigma_pos=sigma * u.arcsec,
                    snr_threshold=snr_threshold, method=method, z_source=z_source)
    for key in ("macro1", "macro2"):
        if key in tab.meta:
            out.meta[key] = tab.meta[key]
    return out

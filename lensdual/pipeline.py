"""Analyses a Python user runs without the command line.

:func:`analyse_knots` is the catalogue-only analysis of ``lensdual run`` with a
``[knots]`` table: the knots of a multiply-imaged galaxy in a published
multiple-image catalogue are paired across its macro-images, their size
magnification is measured with position errors taken from the constellation
itself, and compared with the magnification ratios of lens models.
"""

from dataclasses import dataclass, field

import numpy as np
from astropy import units as u

from ._validation import as_angle_scalar, as_real
from .estimators import DEFAULT_METHOD, estimate_sigma_pos

__all__ = ["KnotAnalysis", "analyse_knots", "knot_report"]


@dataclass(frozen=True)
class KnotAnalysis:
    """Result of :func:`analyse_knots`.

    Attributes
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
    from pathlib import Path

    p = Path(path)
    name = "".join(c if c.isalnum() else "_" for c in (p.parent.name or p.stem)) or "model"
    base, k = name, 2
    while name in taken:
        name, k = f"{base}_{k}", k + 1
    return name


def analyse_knots(catalogue, macro_images, *, knots=None, assign=None, mapping=None, models=(),
                  z_source=None, sigma_pos="auto", method=DEFAULT_METHOD, snr_threshold=3.0):
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
        t1 = np.column_stack([tab["x1"].to_value(u.arcsec), tab["y1"].to_value(u.arcsec)])
        t2 = np.column_stack([tab["x2"].to_value(u.arcsec), tab["y2"].to_value(u.arcsec)])
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


def knot_report(analysis):
    """A text report of a `KnotAnalysis`: assignment, then one block per pair of
    macro-images with every knot's ``mu_size`` and model ratios."""
    lines = [analysis.knot_pairs.summary()]
    for key, tab in analysis.tables.items():
        sigma = analysis.sigma_pos[key]
        how = (f"measured from the residuals of a degree-{analysis.sigma_degree[key]} map"
               if analysis.sigma_degree[key] else "given")
        lines += ["", f"Macro-images {key[0]} (L1) / {key[1]} (L2): {len(tab)} knots, "
                      f"sigma_pos = {sigma.to_value(u.mas):.0f} mas ({how})"]
        names = list(tab.meta.get("models", []))
        head = f"  {'knot':>6} {'mu_size':>8} {'+-ln':>5} {'status':>10}"
        for n in names:
            head += f" {('mu_' + n)[:14]:>14} {'+-ln':>5} {'SNR':>5}"
        lines.append(head)
        for r in tab:
            status = r["mu_size_status"] if "mu_size_status" in tab.colnames else ""
            ln = r["ln_mu_size_err"] if "ln_mu_size_err" in tab.colnames else np.nan
            row = f"  {r['knot']:>6} {r['mu_size']:8.3f} {ln:5.2f} {status:>10}"
            for n in names:
                flag = " !" if r[f"disagree_{n}"] else ""
                row += (f" {r[f'mu_{n}']:14.3f} {r[f'ln_mu_{n}_err']:5.2f} "
                        f"{r[f'snr_{n}']:5.2f}{flag}")
            lines.append(row)
        for n in names:
            bad = tab["knot"][np.asarray(tab[f"disagree_{n}"], bool)]
            agree = int(np.sum(np.asarray(tab["parity"]) == np.asarray(tab[f"parity_{n}"])))
            lines.append(f"  {n}: {len(bad)} of {len(tab)} knots disagree beyond SNR "
                         f"{tab.meta['snr_threshold']:g}"
                         + (f" ({', '.join(str(b) for b in bad)})" if len(bad) else "")
                         + f"; parity agrees for {agree} of {len(tab)}")
    return "\n".join(lines)

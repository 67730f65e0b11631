"""DS9 regions of the sources and the pairs."""

import numpy as np

__all__ = ["ds9_regions"]


def ds9_regions(pairs, catalogs=None, *, radius=0.15):
    """DS9 regions of the detected sources and of the pairs, to load over the images.

    Parameters
    ----------
    pairs : `~astropy.table.Table`
        A pairs table with SkyCoord columns ``sky1`` and ``sky2`` (e.g. the
        output of :func:`~lensdual.duality.check_duality` on measured pairs).
        Pairs are drawn green, ``anomalous`` ones red and untested ones
        (``tested`` False) yellow.
    catalogs : dict, optional
        ``{"L1": table, "L2": table}`` of detections with ``id`` and a
        SkyCoord column ``sky``.
    radius : float
        Circle radius in arcsec (default 0.15).

    Returns
    -------
    regions : dict of str to `regions.Regions`
        ``"pairs"``: a numbered circle on both images of every pair and a line
        between them; ``"L1"``, ``"L2"``: a circle with the id of every
        detection (with ``catalogs``). Write them with
        ``regions["pairs"].write("pairs.reg", format="ds9")``.

    Examples
    --------
    >>> import astropy.units as u
    >>> from astropy.coordinates import SkyCoord
    >>> from astropy.table import QTable
    >>> from lensdual.visualization import ds9_regions
    >>> pairs = QTable({"pair_id": [1, 2],
    ...                 "sky1": SkyCoord([10.0, 10.001] * u.deg, [-5.0, -5.0] * u.deg),
    ...                 "sky2": SkyCoord([10.01, 10.011] * u.deg, [-5.0, -5.0] * u.deg)})
    >>> reg = ds9_regions(pairs)
    >>> len(reg["pairs"])  # two circles and a line per pair
    6
    """
    import astropy.units as u
    from astropy.coordinates import SkyCoord
    from astropy.table import Table
    from regions import CircleSkyRegion, LineSkyRegion, Regions

    from .._pairs_table import SKY_COLUMNS, sky_col

    if not isinstance(pairs, Table):
        raise TypeError(f"pairs must be an astropy Table, got {type(pairs).__name__}")
    for col in SKY_COLUMNS:
        if col not in pairs.colnames or not isinstance(pairs[col], SkyCoord):
            raise ValueError(f"pairs needs a SkyCoord column {col!r} (sky positions of the "
                             "pairs); measure_pairs gives it on images with a WCS")
    r = radius * u.arcsec
    out = []
    ids = pairs["pair_id"] if "pair_id" in pairs.colnames else range(1, len(pairs) + 1)
    for k, pid in enumerate(ids):
        if not (np.isfinite(pairs["sky1"][k].ra.deg) and np.isfinite(pairs["sky2"][k].ra.deg)):
            continue  # not measured: no position to draw
        colour = "green"
        if "anomalous" in pairs.colnames and pairs["anomalous"][k]:
            colour = "red"
        elif "tested" in pairs.colnames and not pairs["tested"][k]:
            colour = "yellow"
        for arc in ("1", "2"):
            meta = {"text": f"{pid}"}
            out.append(CircleSkyRegion(pairs[sky_col(arc)][k], r, meta=meta,
                                       visual={"color": colour}))
        out.append(LineSkyRegion(pairs["sky1"][k], pairs["sky2"][k],
                                 visual={"color": colour, "dash": 1}))
    result = {"pairs": Regions(out)}
    for arc, cat in (catalogs or {}).items():
        if "sky" not in cat.colnames or not isinstance(cat["sky"], SkyCoord):
            raise ValueError(f"catalogs[{arc!r}] needs a SkyCoord column 'sky'")
        idcol = cat["id"] if "id" in cat.colnames else range(len(cat))
        result[arc] = Regions([CircleSkyRegion(sky, r, meta={"text": f"{i}"},
                                               visual={"color": "cyan"})
                               for sky, i in zip(cat["sky"], idcol, strict=True)])
    return result

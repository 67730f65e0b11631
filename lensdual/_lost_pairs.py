"""Pairs lost to masked pixels: a source with no partner because its partner's pixels
are masked.

A source of one arc that the automatic pairing leaves without a partner
(``pairs.meta['unmatched1']``, ``['unmatched2']``) may have lost it to masked
pixels of the other arc (an error map that is zero there, no data): the
partner was never detected. Where the pairing's map puts the partner within
:data:`LOST_RADIUS` pixels of masked pixels, the pair is added to the pairs
to measure, with the partner at its mapped position, and is doubtful with that
reason, so that the report says which pair could not be tested and why
instead of leaving it out without a word.
"""

import numpy as np
from astropy import units as u
from astropy.table import MaskedColumn, QTable, vstack

from ._frames import tangent_to_sky, tangent_xy
from ._pairs_table import PAIR_ID, id_col, sky_col, x_col, y_col
from .photometry._inputs import file_of

__all__ = ["LOST_RADIUS", "with_lost_pairs"]

#: Masked pixels within this many pixels of a partner's mapped position lost it
#: (about a PSF core on a Nyquist-sampled image).
LOST_RADIUS = 3


def map_to_l1(pair_map, xy2):
    """The pairing's map (``pairs.meta['map']``) of L2 positions (N, 2, arcsec) to L1."""
    a_mat = np.asarray(pair_map["A"], dtype=float)
    xy1 = u.Quantity(pair_map["offset"], u.arcsec).value + xy2 @ a_mat.T
    quad = pair_map.get("quadratic")
    if quad is not None:
        d = xy2 - u.Quantity(pair_map["centre"], u.arcsec).value
        terms = np.column_stack([d[:, 0] ** 2, d[:, 0] * d[:, 1], d[:, 1] ** 2])
        xy1 = xy1 + terms @ u.Quantity(quad, 1 / u.arcsec).value
    return xy1


def map_to_l2(pair_map, xy1):
    """The inverse of :func:`map_to_l1` (Newton steps with the affine part)."""
    a_inv = np.linalg.inv(np.asarray(pair_map["A"], dtype=float))
    xy2 = (xy1 - u.Quantity(pair_map["offset"], u.arcsec).value) @ a_inv.T
    for _ in range(20):
        xy2 = xy2 + (xy1 - map_to_l1(pair_map, xy2)) @ a_inv.T
    return xy2


def _masked_near(images, sky):
    """Per position, the most masked pixels within :data:`LOST_RADIUS` in any band of an
    arc, and the file of that band."""
    count = np.zeros(len(sky), dtype=int)
    files = [None] * len(sky)
    for band, image in images.items():
        mask = getattr(image, "mask", None)
        if mask is None or not np.any(mask):
            continue
        mask = np.asarray(mask, dtype=bool)
        ny, nx = mask.shape
        px, py = image.wcs.world_to_pixel(sky)
        for k, (x, y) in enumerate(zip(np.atleast_1d(px), np.atleast_1d(py), strict=True)):
            if not (np.isfinite(x) and np.isfinite(y)):
                continue
            i, j = int(round(float(y))), int(round(float(x)))
            if not (0 <= i < ny and 0 <= j < nx):
                continue  # off the image: not a masked pixel
            window = mask[max(i - LOST_RADIUS, 0):i + LOST_RADIUS + 1,
                          max(j - LOST_RADIUS, 0):j + LOST_RADIUS + 1]
            n = int(np.count_nonzero(window))
            if n > count[k]:
                count[k], files[k] = n, file_of(image) or f"band {band}"
    return count, files


def _lost_rows(pairs, catalogs, images, arc):
    """The unpaired sources of ``arc`` ("1" or "2") whose partner is on masked pixels:
    their ids, own and mapped tangent positions, sky positions and the reasons."""
    other = "2" if arc == "1" else "1"
    ids = list(pairs.meta.get(f"unmatched{arc}") or [])
    cat = catalogs[f"L{arc}"]
    if not ids or cat is None:
        return None
    rows = np.flatnonzero(np.isin(np.asarray(cat["id"]), ids))
    reference = pairs.meta["reference"]
    own_sky = cat["sky"][rows]
    own = np.column_stack(tangent_xy(own_sky, reference))
    mapped = (map_to_l1 if arc == "2" else map_to_l2)(pairs.meta["map"], own)
    mapped_sky = tangent_to_sky(mapped[:, 0], mapped[:, 1], reference)
    count, files = _masked_near(images[f"L{other}"], mapped_sky)
    lost = np.flatnonzero(count > 0)
    if not lost.size:
        return None
    reasons = [f"no L{other} partner in the pairing: the pairing's map puts its L{other} "
               f"image where {files[k]} has {count[k]} masked pixel(s) within {LOST_RADIUS} "
               "pixels (no data, or an error that is zero, negative or not finite)"
               for k in lost]
    return (np.asarray(cat["id"])[rows[lost]], own[lost], mapped[lost], own_sky[lost],
            mapped_sky[lost], reasons)


def with_lost_pairs(pairs, catalogs, images):
    """The pairs of an automatic pairing and the pairs lost to masked pixels.

    Parameters
    ----------
    pairs : `~astropy.table.QTable`
        An automatic pairing (:func:`~lensdual.pairing.pair_constellations`
        of sky catalogues: ``meta`` has ``map``, ``reference``,
        ``unmatched1`` and ``unmatched2``).
    catalogs : dict
        ``{"L1": catalogue, "L2": catalogue}`` that were paired (``id``,
        ``sky``).
    images : dict
        ``{"L1": {band: CCDData}, "L2": ...}``; their ``mask`` is read.

    Returns
    -------
    table : `~astropy.table.QTable`
        ``pairs``, or a copy with one row more per lost pair (next
        ``pair_id``; the lost partner's id masked, its position the mapped
        one; ``residual`` and ``confidence`` NaN).
    reasons : dict
        Row of ``table`` -> why its pair is doubtful.
    """
    meta = pairs.meta
    if meta.get("map") is None or meta.get("reference") is None or len(pairs) == 0:
        return pairs, {}
    extra = []
    for arc in ("2", "1"):
        found = _lost_rows(pairs, catalogs, images, arc)
        if found is None:
            continue
        ids, own, mapped, own_sky, mapped_sky, reasons = found
        n = len(ids)
        other = "2" if arc == "1" else "1"
        part = QTable()
        part[id_col(arc)] = ids
        part[id_col(other)] = MaskedColumn(np.zeros(n, dtype=np.asarray(ids).dtype),
                                           mask=np.ones(n, bool))
        for side, xy, sky in ((arc, own, own_sky), (other, mapped, mapped_sky)):
            part[x_col(side)] = xy[:, 0] * u.arcsec
            part[y_col(side)] = xy[:, 1] * u.arcsec
            part[sky_col(side)] = sky
        extra.append((part, reasons))
    if not extra:
        return pairs, {}
    start = int(np.max(pairs[PAIR_ID])) + 1
    table, reasons = pairs, {}
    for part, why in extra:
        part[PAIR_ID] = np.arange(start, start + len(part))
        start += len(part)
        for name in ("residual", "confidence", "colour_diff"):
            if name in pairs.colnames:
                unit = getattr(pairs[name], "unit", None)
                part[name] = np.full(len(part), np.nan) * (unit if unit is not None else 1)
        part = part[[c for c in pairs.colnames if c in part.colnames]]
        first = len(table)
        table = vstack([table, part], join_type="outer", metadata_conflicts="silent")
        reasons.update({first + k: text for k, text in enumerate(why)})
    table.meta.update(pairs.meta)
    return table, reasons

"""The pairs' positions in a lens model's frame (the comparison and ``lensdual infer``)."""

import numpy as np
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.table import QTable

from .._frames import tangent_to_sky
from .._pairs_table import POSITION_COLUMNS

__all__ = []


def sky_positions(tab, reference):
    """``(sky1, sky2)`` of a pairs table: its SkyCoord columns, else its x/y about
    ``reference``; None when neither is possible."""
    if "sky1" in tab.colnames and "sky2" in tab.colnames:
        sky1, sky2 = tab["sky1"], tab["sky2"]
        if not isinstance(sky1, SkyCoord) or not isinstance(sky2, SkyCoord):
            raise TypeError("pairs['sky1'] and pairs['sky2'] must be SkyCoord columns")
        return sky1, sky2
    if reference is None:
        return None
    xy = [tab[c].to_value(u.arcsec) for c in POSITION_COLUMNS]
    return tangent_to_sky(xy[0], xy[1], reference), tangent_to_sky(xy[2], xy[3], reference)


def with_positions(tab, xy1, xy2):
    """A copy of ``tab`` with x1, y1, x2, y2 replaced (arcsec)."""
    out = QTable(tab, copy=True)
    for name, values in zip(POSITION_COLUMNS, (xy1[0], xy1[1], xy2[0], xy2[1]), strict=True):
        out[name] = np.asarray(values, dtype=float) * u.arcsec
    return out


def frame_reference(tab, reference):
    """The origin of the pairs' frame: ``reference``, else ``meta['reference']`` (or None)."""
    if reference is None:
        reference = tab.meta.get("reference")
        if reference is not None and not (isinstance(reference, SkyCoord)
                                          and reference.isscalar):
            raise TypeError("pairs.meta['reference'] must be a scalar SkyCoord, got "
                            f"{reference!r}")
    return reference


def in_lenstool_frame(tab, lt_model, sky):
    """A copy of ``tab`` with the positions in the Lenstool model's frame."""
    xy1 = lt_model.to_model_frame(sky[0]).to_value(u.arcsec).T
    xy2 = lt_model.to_model_frame(sky[1]).to_value(u.arcsec).T
    return with_positions(tab, xy1, xy2)

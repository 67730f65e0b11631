"""The one tangent-plane frame of lensdual.

Every pairs table gives positions ``x``, ``y`` in arcsec in a gnomonic (TAN)
projection about a tangent point, with **x to the West** and **y to the
North** (the orientation of the sky as seen, and of Lenstool's model frame).
This module is the only place that converts between that frame and the sky;
a sign slip here would mirror every constellation, so the round trip and the
orientation are tested in ``tests/test_frames.py``.
"""

import numpy as np
from astropy import units as u
from astropy.coordinates import (
    CartesianRepresentation,
    SkyCoord,
    SkyOffsetFrame,
    UnitSphericalRepresentation,
)

__all__ = ["ARCSEC_PER_RAD", "mean_direction", "tangent_to_sky", "tangent_xy"]

#: Arcseconds in one radian.
ARCSEC_PER_RAD = (1.0 * u.rad).to_value(u.arcsec)


def tangent_xy(sky, reference):
    """Gnomonic offsets ``(x, y)`` in arcsec of ``sky`` about ``reference``.

    ``x`` grows to the West, ``y`` to the North. Returns two float arrays of
    the shape of ``sky``.
    """
    c = sky.transform_to(SkyOffsetFrame(origin=reference)).cartesian
    xc, yc, zc = c.x.value, c.y.value, c.z.value
    return -yc / xc * ARCSEC_PER_RAD, zc / xc * ARCSEC_PER_RAD


def tangent_to_sky(x, y, reference):
    """Inverse of :func:`tangent_xy`: the SkyCoord (in ``reference``'s frame) of
    offsets ``x`` (West), ``y`` (North) in arcsec."""
    xi = -np.asarray(x, dtype=np.float64) / ARCSEC_PER_RAD
    eta = np.asarray(y, dtype=np.float64) / ARCSEC_PER_RAD
    rep = CartesianRepresentation(np.ones_like(xi), xi, eta).represent_as(
        UnitSphericalRepresentation)
    frame = SkyOffsetFrame(origin=reference)
    return SkyCoord(frame.realize_frame(rep)).transform_to(reference.frame.replicate_without_data())


def mean_direction(*skies):
    """The mean direction (normalised mean of the unit vectors, NaNs ignored) of
    SkyCoord arrays, in the frame of the first."""
    frame = skies[0].frame.replicate_without_data()
    xyz = np.concatenate(
        [np.atleast_2d(s.transform_to(frame).cartesian.xyz.value.reshape(3, -1).T) for s in skies])
    xyz = np.nanmean(xyz, axis=0)
    rep = CartesianRepresentation(*(xyz / np.linalg.norm(xyz)))
    return SkyCoord(frame.realize_frame(rep.represent_as(UnitSphericalRepresentation)))

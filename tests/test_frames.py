"""The one tangent-plane frame (lensdual._frames): orientation and round trip."""

import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import SkyCoord

from lensdual._frames import mean_direction, tangent_to_sky, tangent_xy


@pytest.mark.parametrize("dec0", [-70.0, -12.0, 0.0, 22.4, 85.0])
def test_orientation_west_north(dec0):
    ref = SkyCoord(177.4 * u.deg, dec0 * u.deg)
    # one arcsec East (RA grows) is x = -1; one arcsec North is y = +1
    east = ref.directional_offset_by(90 * u.deg, 1 * u.arcsec)
    north = ref.directional_offset_by(0 * u.deg, 1 * u.arcsec)
    x, y = tangent_xy(SkyCoord([east.ra, north.ra], [east.dec, north.dec]), ref)
    np.testing.assert_allclose(x, [-1.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(y, [0.0, 1.0], atol=1e-9)


def test_round_trip_and_gnomonic_against_wcs():
    from astropy.wcs import WCS

    ref = SkyCoord(10.0 * u.deg, -45.0 * u.deg)
    rng = np.random.default_rng(1)
    x, y = rng.uniform(-60, 60, (2, 50))
    sky = tangent_to_sky(x, y, ref)
    x2, y2 = tangent_xy(sky, ref)
    np.testing.assert_allclose(x2, x, atol=1e-9)
    np.testing.assert_allclose(y2, y, atol=1e-9)
    # independent reference: a TAN WCS with the tangent point at ref, -1 arcsec per
    # pixel in RA: CDELT1 < 0, so pixel x grows West, as x does
    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.crval = [ref.ra.deg, ref.dec.deg]
    w.wcs.crpix = [1.0, 1.0]  # FITS pixels are 1-based: 0-based pixel 0 at ref
    w.wcs.cdelt = [-1.0 / 3600.0, 1.0 / 3600.0]
    px, py = w.world_to_pixel(sky)
    np.testing.assert_allclose(px, x, atol=1e-7)
    np.testing.assert_allclose(py, y, atol=1e-7)


def test_mean_direction_ignores_nan_and_averages_unit_vectors():
    a = SkyCoord([359.9, 0.1] * u.deg, [0.0, 0.0] * u.deg)
    b = SkyCoord([np.nan] * u.deg, [np.nan] * u.deg)
    m = mean_direction(a, b)
    assert abs(m.dec.deg) < 1e-12
    assert abs(((m.ra.deg + 180) % 360) - 180) < 1e-9

"""The resolved-source fit (``source_model="resolved"``) against closed forms.

The references are plain numpy: a Gaussian source of covariance ``C`` seen
through a Gaussian PSF of variance ``p^2`` is a Gaussian of covariance
``p^2 + C`` (covariances add); integrated over the pixels of an
axis-aligned ellipse it is a product of error-function differences; a fit of
the PSF's amplitude alone to it recovers ``sqrt(2) p / sqrt(2 p^2 + c)`` of
the flux per axis.
"""

import warnings

import numpy as np
import pytest
from astropy.nddata import NDData, StdDevUncertainty
from scipy.special import erf

from lensdual.exceptions import LensdualWarning
from lensdual.photometry import UNUSABLE_FLAGS, PhotometryFlag, psf_photometry

FWHM = 2.5  # pixels
SIGMA = FWHM / (2.0 * np.sqrt(2.0 * np.log(2.0)))
N = 31
PC = 0.121 / 40.0  # pixels per pc: 0.121 mas at z = 2.2, 40 mas pixels
HALF_LIGHT_PER_SIGMA = np.sqrt(2.0 * np.log(2.0))


def _side(t, s):
    """Pixel integral of a 1-D unit Gaussian of sigma ``s`` centred at 0, pixels at ``t``."""
    k = 1.0 / (np.sqrt(2.0) * s)
    return 0.5 * (erf((t + 0.5) * k) - erf((t - 0.5) * k))


def gaussian_image(flux, x0, y0, cxx, cyy, sky=0.0, fwhm=FWHM):
    """The pixel-integrated image of a source of axis-aligned Gaussian covariance
    diag(cxx, cyy) through a Gaussian PSF of FWHM ``fwhm``: covariances add."""
    sigma = fwhm / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    yy, xx = np.mgrid[:N, :N]
    return sky + flux * _side(xx - x0, np.sqrt(sigma**2 + cxx)) * _side(yy - y0,
                                                                       np.sqrt(sigma**2 + cyy))


def measure(image, model, noise=0.05, start=(15.2, 14.8), fwhm=FWHM, **kw):
    nd = NDData(image, uncertainty=StdDevUncertainty(np.full(image.shape, noise)))
    return psf_photometry(nd, [start], psf=fwhm, background="constant", source_model=model,
                          **kw)


def test_the_fine_kernel_is_the_closed_form_of_gaussians():
    """PSF (x) Gaussian of the fine-grid convolution = the Gaussian of summed covariances,
    at a sub-pixel offset, pixel-integrated."""
    from lensdual.photometry._profiles import _GaussianProfile
    from lensdual.photometry._resolved import _FineKernel

    kernel = _FineKernel(_GaussianProfile(FWHM, None), 8, 4.0)
    my, mx = np.mgrid[-6:7, -6:7]
    cov = np.diag([1.7**2, 0.4**2])
    got = kernel.model(cov, mx, my, (0.3, -0.2))
    want = _side(mx - 0.3, np.sqrt(SIGMA**2 + cov[0, 0])) * _side(my + 0.2,
                                                                   np.sqrt(SIGMA**2 + cov[1, 1]))
    assert np.max(np.abs(got - want)) < 1e-4 * want.max()
    # a rotated covariance: the same image turned (the model's moments are p^2 + C)
    rot = np.array([[np.cos(0.6), -np.sin(0.6)], [np.sin(0.6), np.cos(0.6)]])
    turned = kernel.model(rot @ cov @ rot.T, mx, my, (0.0, 0.0))
    total = turned.sum()
    mxx = np.sum(turned * mx * mx) / total
    mxy = np.sum(turned * mx * my) / total
    want_c = rot @ cov @ rot.T + (SIGMA**2 + 1.0 / 12.0) * np.eye(2)
    assert total == pytest.approx(1.0, abs=2e-3)
    assert mxx == pytest.approx(want_c[0, 0], rel=0.02)
    assert mxy == pytest.approx(want_c[0, 1], rel=0.02)


def test_the_psf_fit_loses_the_closed_form_fraction_and_the_resolved_fit_none():
    """A resolved Gaussian: the PSF-only amplitude fit recovers sqrt(2)p/sqrt(2p^2+c) per
    axis (the closed form, p^2 the pixel-integrated PSF's variance); the resolved fit
    recovers the whole flux and the source's covariance."""
    cxx, cyy = 2.0**2, 0.5**2
    image = gaussian_image(1000.0, 15.3, 14.9, cxx, cyy)
    p2 = SIGMA**2 + 1.0 / 12.0
    expected = np.prod([np.sqrt(2 * p2) / np.sqrt(2 * p2 + c) for c in (cxx, cyy)])
    point = psf_photometry(image, [(15.3, 14.9)], psf=FWHM, background="none",
                           xy_bounds=0.01, fit_shape=21)
    assert point["flux"][0] / 1000.0 == pytest.approx(expected, rel=0.01)
    res = measure(image, "resolved", fit_shape=15)
    assert res["flux"][0] == pytest.approx(1000.0, rel=2e-3)
    assert res["size"][0] == pytest.approx(2.0, rel=0.02)
    assert res["size_minor"][0] == pytest.approx(0.5, rel=0.1)
    assert res["size_angle"][0] % 180 == pytest.approx(0.0, abs=1.0) or \
        res["size_angle"][0] % 180 == pytest.approx(180.0, abs=1.0)
    assert res["size_snr"][0] > 10
    assert res["flux_point"][0] == pytest.approx(measure(image, "point", fit_shape=15)["flux"][0])
    assert res["flags"][0] == 0


def test_a_point_source_has_size_zero_and_the_psf_flux():
    rng = np.random.default_rng(3)
    image = gaussian_image(400.0, 15.3, 14.9, 0.0, 0.0, sky=2.0) + rng.normal(0, 0.05, (N, N))
    point = measure(image, "point")
    res = measure(image, "resolved")
    assert abs(res["size_snr"][0]) < 3
    assert abs(res["size"][0]) < 0.3
    assert res["flux"][0] == pytest.approx(point["flux"][0], abs=2 * res["flux_err"][0])
    assert res["flux_err"][0] >= point["flux_err"][0]  # the size costs some precision
    assert res["x_fit"][0] == pytest.approx(15.3, abs=0.02)


@pytest.mark.parametrize("r_pc, old_bias", [(5.0, 0.02), (20.0, 0.25)])
def test_a_cluster_stretched_20_and_10_times_keeps_its_flux_ratio(r_pc, old_bias):
    """A round cluster of r_eff seen stretched mu_t = 20 and 10 times along the arc (x),
    1.3 times across, through the F150W PSF (FWHM 50 mas, 1.25 pixels of 40 mas): the
    PSF fit's ratio is biased (about 3 % at 5 pc, 30 % at 20 pc), the resolved fit's by
    at most 1 %."""
    s = r_pc * PC / HALF_LIGHT_PER_SIGMA  # source-plane sigma, pixels
    fluxes = {}
    for model in ("point", "resolved"):
        f = []
        for mu_t in (20.0, 10.0):
            image = gaussian_image(10.0 * mu_t * 1.3, 15.3, 14.9, (s * mu_t) ** 2,
                                   (s * 1.3) ** 2, sky=1.0, fwhm=1.25)
            f.append(measure(image, model, fit_shape=9, fwhm=1.25)["flux"][0])
        fluxes[model] = np.log(f[0] / f[1] / 2.0)
    assert abs(fluxes["point"]) > old_bias
    assert abs(fluxes["resolved"]) <= 0.01


def test_a_source_far_wider_than_its_box_is_too_resolved():
    image = gaussian_image(1000.0, 15.3, 14.9, 5.0**2, 1.0, sky=1.0)
    with pytest.warns(LensdualWarning, match="1 of 1 fits flagged"):
        res = measure(image, "resolved", fit_shape=9)
    assert res["flags"][0] & PhotometryFlag.TOO_RESOLVED
    assert PhotometryFlag.TOO_RESOLVED & UNUSABLE_FLAGS
    assert res["flux_outside"][0] > 0.1 or res["size"][0] >= 5.9


def test_a_psf_much_narrower_than_the_sources_suggests_the_resolved_fit():
    images = [gaussian_image(800.0, 15.3, 14.9, 3.0**2, 3.0**2)]
    with pytest.warns(LensdualWarning, match=r"times narrower than the point sources.*"
                                             r"source_model='resolved'"):
        measure(images[0], "point", fit_shape=15)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = measure(images[0], "resolved", fit_shape=15)
    assert res["flux"][0] == pytest.approx(800.0, rel=0.01)


def test_only_a_given_gaussian_fwhm_is_checked_against_the_sources(monkeypatch):
    """A fitted FWHM is the sources' own width: the narrow-PSF check runs only for
    a Gaussian PSF of given FWHM."""
    from lensdual.photometry import ArcPSFPhotometry

    calls = []
    original = ArcPSFPhotometry._check_resolved
    monkeypatch.setattr(ArcPSFPhotometry, "_check_resolved",
                        lambda self, *a: calls.append(a) or original(self, *a))
    image = gaussian_image(800.0, 15.3, 14.9, 0.0, 0.0)
    measure(image, "point", fwhm=None)
    assert calls == []
    measure(image, "point")
    assert len(calls) == 1


def test_an_unknown_source_model_is_refused():
    with pytest.raises(ValueError, match="source_model must be one of"):
        psf_photometry(np.zeros((9, 9)), [(4, 4)], psf=2.0, source_model="extended")


def test_measure_pairs_reports_the_sizes_in_mas():
    from astropy.nddata import CCDData
    from astropy.table import QTable
    from astropy.wcs import WCS

    from lensdual.photometry import measure_pairs

    def cutout(flux, cxx, dec):
        wcs = WCS(naxis=2)
        wcs.wcs.ctype = ["RA---TAN", "DEC--TAN"]
        wcs.wcs.crval, wcs.wcs.crpix = [110.8, dec], [16, 16]
        wcs.wcs.cdelt = [-0.04 / 3600, 0.04 / 3600]
        data = gaussian_image(flux, 15.3, 14.9, cxx, 0.2, sky=1.0)
        return CCDData(data, unit="nJy", wcs=wcs,
                       uncertainty=StdDevUncertainty(np.full(data.shape, 0.05)))

    l1 = {"F150W": cutout(600.0, 1.5**2, -73.45)}
    l2 = {"F150W": cutout(300.0, 0.75**2, -73.4505)}
    pairs = QTable({"sky1": l1["F150W"].wcs.pixel_to_world([15], [15]),
                    "sky2": l2["F150W"].wcs.pixel_to_world([15], [15])})
    out = measure_pairs(l1, l2, pairs, psf=FWHM, background="constant",
                        source_model="resolved")
    assert out["size1_F150W"].unit == "mas"
    assert out["size1_F150W"][0].value == pytest.approx(60.0, rel=0.03)
    assert out["size2_F150W"][0].value == pytest.approx(30.0, rel=0.05)
    assert out["size_snr1_F150W"][0] > 3
    assert float(out["flux1_F150W"][0] / out["flux2_F150W"][0]) == pytest.approx(2.0, rel=0.005)
    assert out.meta["photometry"]["source_model"] == "resolved"

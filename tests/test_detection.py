"""Tests of lensdual.detection (the point-source filter chain of Appendix C).

The plain-numpy twins of the Numba kernels, and of the whole chain
(:func:`numpy_chain`), live here; ``benchmarks/bench_detection.py`` imports
:func:`numpy_chain` and :func:`make_scene` from this module.
"""

import warnings

import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.nddata import CCDData, NDData
from astropy.table import QTable
from astropy.wcs import WCS
from scipy.ndimage import gaussian_filter

from lensdual.detection import PointSourceFilter, PointSourceMap, _kernels, find_point_sources
from lensdual.exceptions import LensdualWarning, NoDetectionsWarning

BANDS = ("F150W", "F200W")
PSF_SIGMA = {"F150W": 0.85, "F200W": 1.0}  # FWHM 2.0 and 2.35 px
ARC_PEAK = {"F150W": 100.0, "F200W": 80.0}
COLOUR = {"F150W": 1.0, "F200W": 0.9}
ARC_CENTRE = (100.0, -60.0)  # (x, y) of the centre of curvature, below the image
ARC_RADIUS = 150.0
ARC_WIDTH = 8.0  # Gaussian sigma across the arc, px
SHAPE = (160, 200)


# ---------------------------------------------------------------------------
# synthetic scenes
# ---------------------------------------------------------------------------


def source_positions():
    """(x, y, flux) of the injected point sources: 6 on the arc, 4 off it."""
    xc, yc = ARC_CENTRE
    rows = []
    for phi, drho, flux in [
        (-0.5, -3.2, 300),
        (-0.3, 2.1, 260),
        (-0.1, 0.3, 350),
        (0.12, -2.4, 280),
        (0.31, 3.3, 400),
        (0.52, 1.2, 250),
    ]:
        rho = ARC_RADIUS + drho
        rows.append((xc + rho * np.sin(phi), yc + rho * np.cos(phi), flux))
    rows += [(30.3, 30.7, 260), (170.6, 25.2, 300), (60.2, 130.4, 330), (150.8, 140.1, 270)]
    return np.array(rows)


def make_scene(shape=SHAPE, noise=1.0, seed=1, sources=None, scale=1.0):
    """Two bands: a bright smooth arc (a ring segment) plus Gaussian point sources.

    ``shape`` larger than SHAPE tiles nothing: the arc and sources keep their
    pixel positions (the benchmark uses big images of pure arc + noise + sources).
    """
    rng = np.random.default_rng(seed)
    if sources is None:
        sources = source_positions()
    ny, nx = shape
    y, x = np.mgrid[:ny, :nx].astype(float)
    xc, yc = ARC_CENTRE
    rho = np.hypot(x - xc, y - yc)
    phi = np.arctan2(x - xc, y - yc)
    arc = np.exp(-0.5 * ((rho - ARC_RADIUS) / ARC_WIDTH) ** 2 - 0.5 * (phi / 0.45) ** 2)
    del x, y, rho, phi
    out = {}
    for band in BANDS:
        s = PSF_SIGMA[band]
        img = ARC_PEAK[band] * scale * arc
        r = int(np.ceil(6 * s))
        for sx, sy, flux in sources:
            i0, j0 = int(round(sy)), int(round(sx))
            yy, xx = np.mgrid[i0 - r : i0 + r + 1, j0 - r : j0 + r + 1]
            amp = COLOUR[band] * flux * scale / (2 * np.pi * s**2)
            img[i0 - r : i0 + r + 1, j0 - r : j0 + r + 1] += amp * np.exp(
                -0.5 * ((xx - sx) ** 2 + (yy - sy) ** 2) / s**2
            )
        img += rng.normal(scale=noise * scale, size=shape)
        out[band] = img
    return out


def match(table, truth, tol=0.5):
    """Distances from every true source to its nearest detection, and vice versa."""
    d = np.hypot(
        np.asarray(table["x_centroid"])[:, None] - truth[:, 0],
        np.asarray(table["y_centroid"])[:, None] - truth[:, 1],
    )
    return d.min(axis=0), d.min(axis=1)


def make_wcs(shape=SHAPE):
    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.crval = [64.04, -24.07]
    w.wcs.crpix = [shape[1] / 2, shape[0] / 2]
    w.wcs.cdelt = [-0.03 / 3600, 0.03 / 3600]
    return w


@pytest.fixture(scope="module")
def scene():
    return make_scene()


# ---------------------------------------------------------------------------
# plain-numpy twins
# ---------------------------------------------------------------------------


def blur(image, sigma):
    return gaussian_filter(image, sigma, output=np.float64, mode="reflect", truncate=4.0)


def has_nonfinite_np(data):
    return not np.isfinite(data).all()


def band_statistics_np(datas, nums, wblurs, valids, masked):
    """Twin of _kernels.band_statistics: (pos_sum, count, coadd, wcommon)."""
    shape = datas[0].shape
    common = np.ones(shape, dtype=bool)
    pos_sum, count = [], []
    coadd = np.zeros(shape)
    for d, n, w, v, m in zip(datas, nums, wblurs, valids, masked, strict=True):
        if m:
            with np.errstate(invalid="ignore", divide="ignore"):
                r = d[v] - n[v] / w[v]
            common &= v
        else:
            r = (d - n).ravel()
        pos_sum.append(np.maximum(r, 0.0).sum())
        count.append(r.size)
        coadd = coadd + np.where(v if m else True, d, 0.0)
    coadd = np.where(common, coadd, 0.0)
    return np.array(pos_sum), np.array(count), coadd, common.astype(float)


def filter_pixels_np(
    datas, nums, wblurs, valids, masked, levels, norm_num, norm_w, any_masked, floor, snr,
    threshold,
):  # fmt: skip
    """Twin of _kernels.filter_pixels: (residuals, coadded, normalized, candidates)."""
    shape = datas[0].shape
    residuals = []
    composite = np.ones(shape, dtype=bool)
    total = np.zeros(shape)
    for d, n, w, v, m, level in zip(datas, nums, wblurs, valids, masked, levels, strict=True):
        with np.errstate(invalid="ignore", divide="ignore"):
            r = np.where(v, d - n / w, 0.0) if m else d - n
        r = np.where(r < 0.0, 0.0, r)
        residuals.append(r)
        composite &= r > level
        total = total + r
    with np.errstate(invalid="ignore", divide="ignore"):
        s = norm_num / norm_w if any_masked else norm_num
        den = np.where(s > floor, s, floor)
        v = np.where(den > 0.0, total / den, 0.0)
    coadded = np.where(composite, total, 0.0)
    normalized = np.where(composite, v, 0.0)
    candidates = composite & (normalized > threshold) & (coadded > snr)
    return residuals, coadded, normalized, candidates


def numpy_chain(
    images, smooth_sigma=5.0, threshold_factor=3.0, norm_sigma=3.0, threshold=0.3, min_snr=5.0
):
    """The whole filter chain in plain numpy (the reference of tests and benchmark).

    ``images``: list of 2-D float64 arrays (NaN = invalid) or (data, mask) pairs.
    Returns a dict with the same maps as PointSourceMap.
    """
    datas, valids = [], []
    for item in images:
        data, mask = item if isinstance(item, tuple) else (item, None)
        valid = np.isfinite(data)
        if mask is not None:
            valid &= ~mask
        datas.append(data)
        valids.append(valid)
    masked = [not v.all() for v in valids]
    any_masked = any(masked)
    residuals = []
    common = np.ones(datas[0].shape, dtype=bool)
    means, sigmas = [], []
    for d, v, m in zip(datas, valids, masked, strict=True):
        if m:
            with np.errstate(invalid="ignore", divide="ignore"):
                s = blur(np.where(v, d, 0.0), smooth_sigma) / blur(v.astype(float), smooth_sigma)
            r = np.where(v, d - s, 0.0)
        else:
            s = blur(d, smooth_sigma)
            r = d - s
        common &= v
        pos = np.maximum(r, 0.0)
        means.append(pos[v].mean())
        step = max(1, int((d.size / 2**18) ** 0.5))
        rs = r[::step, ::step][v[::step, ::step]]
        sigmas.append(1.482602218505602 * np.median(np.abs(rs - np.median(rs))))
        residuals.append(pos)
    flags = [r > threshold_factor * m for r, m in zip(residuals, means, strict=True)]
    composite = np.logical_and.reduce(flags)
    coadd_raw = np.where(common, sum(np.where(common, d, 0.0) for d in datas), 0.0)
    if any_masked:
        with np.errstate(invalid="ignore", divide="ignore"):
            norm = blur(coadd_raw, norm_sigma) / blur(common.astype(float), norm_sigma)
    else:
        norm = blur(coadd_raw, norm_sigma)
    snr_level = min_snr * np.sqrt(np.sum(np.square(sigmas)))
    floor = snr_level / threshold if threshold > 0 else 0.0
    coadded = np.where(composite, sum(residuals), 0.0)
    den = np.maximum(norm, floor)
    with np.errstate(invalid="ignore", divide="ignore"):
        normalized = np.where(composite & (den > 0), coadded / den, 0.0)
    candidates = (normalized > threshold) & (coadded > snr_level)
    return {
        "residuals": residuals,
        "means": np.array(means),
        "noise": np.array(sigmas),
        "floor": floor,
        "coadded": coadded,
        "normalized": normalized,
        "candidates": candidates,
    }


# ---------------------------------------------------------------------------
# kernels against their twins
# ---------------------------------------------------------------------------


def random_bands(rng, nb, shape, masked):
    datas, nums, wblurs, valids = [], [], [], []
    for m in masked:
        d = rng.normal(size=shape) + 3.0 * rng.random(shape)
        if m:
            v = rng.random(shape) > 0.2
            d[~v] = np.nan
            num = blur(np.where(v, d, 0.0), 2.0)
            w = blur(v.astype(float), 2.0)
        else:
            v = np.zeros((1, 1), dtype=bool)
            num = blur(d, 2.0)
            w = np.zeros((1, 1))
        datas.append(d)
        nums.append(num)
        wblurs.append(w)
        valids.append(v)
    return tuple(datas), tuple(nums), tuple(wblurs), tuple(valids)


def test_has_nonfinite_matches_numpy():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(30, 40))
    assert _kernels.has_nonfinite(x) is has_nonfinite_np(x) is False
    for bad in (np.nan, np.inf, -np.inf):
        y = x.copy()
        y[17, 3] = bad
        assert _kernels.has_nonfinite(y) is has_nonfinite_np(y) is True


@pytest.mark.parametrize("masked", [(False,), (False, False), (True, False), (True, True, False)])
def test_kernels_match_numpy_twins(masked):
    rng = np.random.default_rng(len(masked) + 10 * sum(masked))
    shape = (37, 53)
    datas, nums, wblurs, valids = random_bands(rng, len(masked), shape, masked)
    mk = np.array(masked)
    any_masked = bool(mk.any())
    coadd = np.empty(shape)
    wcommon = np.empty(shape) if any_masked else np.zeros((1, 1))
    pos_sum, count = _kernels.band_statistics(
        datas, nums, wblurs, valids, mk, any_masked, coadd, wcommon
    )
    ref_pos, ref_count, ref_coadd, ref_w = band_statistics_np(datas, nums, wblurs, valids, mk)
    np.testing.assert_allclose(pos_sum, ref_pos, rtol=1e-12)
    np.testing.assert_array_equal(count, ref_count)
    np.testing.assert_array_equal(coadd, ref_coadd)
    if any_masked:
        np.testing.assert_array_equal(wcommon, ref_w)

    levels = 0.8 * pos_sum / count
    norm_num = blur(coadd, 1.5)
    norm_w = blur(wcommon, 1.5) if any_masked else np.zeros((1, 1))
    args = (datas, nums, wblurs, valids, mk, levels, norm_num, norm_w, any_masked, 4.0, 1.0, 0.3)
    ref = filter_pixels_np(*args)
    residuals = tuple(np.empty(shape) for _ in masked)
    out = np.empty(shape), np.empty(shape), np.empty(shape, dtype=bool)
    _kernels.filter_pixels(*args, residuals, *out)
    for r, rr in zip(residuals, ref[0], strict=True):
        np.testing.assert_array_equal(r, rr)
    for o, rr in zip(out, ref[1:], strict=True):
        np.testing.assert_array_equal(o, rr)
    assert out[2].any() and not out[2].all()

    # the documented in-place use: residuals over nums, co-add over norm_num
    nums2 = tuple(n.copy() for n in nums)
    norm2 = norm_num.copy()
    normalized = np.empty(shape)
    cand = np.empty(shape, dtype=bool)
    args2 = (datas, nums2, wblurs, valids, mk, levels, norm2, norm_w, any_masked, 4.0, 1.0, 0.3)
    _kernels.filter_pixels(*args2, nums2, norm2, normalized, cand)
    for r, rr in zip(nums2, ref[0], strict=True):
        np.testing.assert_array_equal(r, rr)
    np.testing.assert_array_equal(norm2, ref[1])
    np.testing.assert_array_equal(normalized, ref[2])
    np.testing.assert_array_equal(cand, ref[3])


def compare_with_chain(result, ref, bands):
    for k, band in enumerate(bands):
        np.testing.assert_array_equal(result.residuals[band], ref["residuals"][k])
        np.testing.assert_allclose(result.means[band], ref["means"][k], rtol=1e-12)
        np.testing.assert_allclose(result.noise[band], ref["noise"][k], rtol=1e-12)
    np.testing.assert_allclose(result.floor, ref["floor"], rtol=1e-12)
    np.testing.assert_array_equal(result.coadded, ref["coadded"])
    np.testing.assert_allclose(result.normalized, ref["normalized"], rtol=1e-12, atol=0)
    np.testing.assert_array_equal(result.candidates, ref["candidates"])


def test_filter_matches_numpy_chain(scene):
    result = PointSourceFilter()(scene)
    compare_with_chain(result, numpy_chain([scene[b] for b in BANDS]), BANDS)
    assert result.candidates.any()


def test_filter_matches_numpy_chain_with_nan_and_mask(scene):
    a = scene["F150W"].copy()
    a[100:110, 20:35] = np.nan
    mask = np.zeros(SHAPE, dtype=bool)
    mask[40:60, 150:158] = True
    pars = {"smooth_sigma": 4, "threshold_factor": 2.5, "norm_sigma": 2.5, "threshold": 0.25}
    result = PointSourceFilter(**pars, min_snr=4)(
        {"F150W": a, "F200W": NDData(scene["F200W"], mask=mask)}
    )
    ref = numpy_chain([a, (scene["F200W"], mask)], 4.0, 2.5, 2.5, 0.25, 4.0)
    compare_with_chain(result, ref, BANDS)


# ---------------------------------------------------------------------------
# detection on synthetic arcs
# ---------------------------------------------------------------------------


def test_finds_every_point_source_and_nothing_else(scene):
    truth = source_positions()
    table = find_point_sources(scene)
    assert isinstance(table, QTable)
    to_det, to_truth = match(table, truth)
    assert len(table) == len(truth)
    assert to_det.max() < 0.5, to_det
    assert to_truth.max() < 0.5, to_truth
    assert list(table["id"]) == list(range(1, len(table) + 1))
    expected = ["id", "x_centroid", "y_centroid", "peak", "area", "peak_F150W", "peak_F200W"]
    assert table.colnames == expected
    assert table["area"].unit == u.pix**2
    assert np.all(table["area"].value >= 1)
    assert np.all(table["peak"] > 0.3)
    # the residual peaks follow the injected PSFs: F150W is sharper and brighter
    assert np.all(table["peak_F150W"] > table["peak_F200W"])
    meta = table.meta
    assert meta["bands"] == list(BANDS)
    assert meta["smooth_sigma"] == 5 and meta["threshold_factor"] == 3
    assert meta["norm_sigma"] == 3 and meta["threshold"] == 0.3
    assert set(meta["means"]) == set(BANDS)
    assert "lensdual" in meta["version"] and "date" in meta


@pytest.mark.parametrize("seed", [2, 3])
@pytest.mark.parametrize("noise", [0.5, 3.0])
def test_detection_across_noise_realisations(seed, noise):
    truth = source_positions()
    table = find_point_sources(make_scene(noise=noise, seed=seed))
    to_det, to_truth = match(table, truth)
    assert len(table) == len(truth)
    assert to_det.max() < 0.5 and to_truth.max() < 0.5


def test_result_object(scene):
    result = PointSourceFilter()(scene)
    assert isinstance(result, PointSourceMap)
    assert result.bands == BANDS
    assert result.shape == SHAPE
    assert result.candidates.dtype == bool and result.normalized.dtype == np.float64
    assert "PointSourceMap" in repr(result) and "F150W" in repr(result)
    flags = result.flags
    for band in BANDS:
        assert np.all(result.residuals[band] >= 0)
        np.testing.assert_array_equal(
            flags[band], result.residuals[band] > 3.0 * result.means[band]
        )
    np.testing.assert_array_equal(result.composite, flags["F150W"] & flags["F200W"])
    assert not np.any(result.candidates & ~result.composite)
    assert np.all(result.normalized[~result.composite] == 0)
    # the noise estimate is close to the injected noise (the arc inflates it a bit)
    for band in BANDS:
        assert 0.9 < result.noise[band] < 2.0
    assert result.unit is None and result.wcs is None


def test_sequence_input_and_single_band(scene):
    seq = PointSourceFilter()([scene["F150W"], scene["F200W"]])
    dct = PointSourceFilter()(scene)
    assert seq.bands == ("0", "1")
    np.testing.assert_array_equal(seq.candidates, dct.candidates)
    table = find_point_sources((scene["F150W"],))
    assert "peak_0" in table.colnames and "peak_1" not in table.colnames
    to_det, _ = match(table, source_positions())
    assert to_det.max() < 0.5


def test_paper_chain_without_noise_floor(scene):
    """min_snr=0 is the literal chain: background noise explodes the normalisation."""
    literal = PointSourceFilter(min_snr=0)(scene)
    default = PointSourceFilter()(scene)
    assert literal.floor == 0 and literal.snr_level == 0
    assert literal.candidates.sum() > default.candidates.sum()
    # on the bright arc nothing changes
    arc = blur(scene["F150W"] + scene["F200W"], 3) > default.floor
    np.testing.assert_array_equal(literal.candidates[arc], default.candidates[arc])


def test_inputs_not_modified(scene):
    a = scene["F150W"].copy()
    a[5:9, 5:9] = np.nan
    b = scene["F200W"].astype(np.float32)
    mask = np.zeros(SHAPE, dtype=bool)
    mask[0:3] = True
    nd = NDData(b, mask=mask)
    copies = a.copy(), b.copy(), mask.copy()
    result = PointSourceFilter()({"F150W": a, "F200W": nd})
    np.testing.assert_array_equal(a, copies[0])
    np.testing.assert_array_equal(nd.data, copies[1])
    np.testing.assert_array_equal(nd.mask, copies[2])
    assert not np.shares_memory(result.residuals["F150W"], a)


def test_array_layouts_and_dtypes(scene):
    """Read-only, Fortran-ordered, big-endian and float32 inputs give the same maps."""
    ref = PointSourceFilter()(scene)
    a = scene["F150W"].copy()
    a.flags.writeable = False
    b = np.asfortranarray(scene["F200W"]).astype(">f8")
    result = PointSourceFilter()({"F150W": a, "F200W": NDData(b, mask=False)})
    np.testing.assert_array_equal(result.candidates, ref.candidates)
    np.testing.assert_array_equal(result.normalized, ref.normalized)
    mask = np.asfortranarray(np.zeros(SHAPE, dtype=bool))
    mask[3:6, 3:6] = True
    c = scene["F200W"].astype(np.float32)[::-1][::-1]
    masked = PointSourceFilter()({"F150W": a, "F200W": NDData(c, mask=mask)})
    assert not masked.composite[3:6, 3:6].any()
    assert masked.candidates.sum() > 0


# ---------------------------------------------------------------------------
# NaN, masks, NDData / CCDData, units, WCS
# ---------------------------------------------------------------------------


def test_nan_and_masked_pixels_do_not_poison_the_blurs(scene):
    truth = source_positions()
    a = scene["F150W"].copy()
    b = scene["F200W"].copy()
    a[70:80, 95:105] = np.nan  # on the flank of the arc
    a[120:160, 0:30] = np.inf
    mask = np.zeros(SHAPE, dtype=bool)
    mask[20:40, 100:125] = True  # sky
    b[mask] = 1e6  # garbage under the mask must not leak
    images = {"F150W": a, "F200W": CCDData(b, unit="adu", mask=mask)}
    result = PointSourceFilter()(images)
    assert np.all(np.isfinite(result.normalized))
    bad = ~np.isfinite(a) | mask
    assert not result.candidates[bad].any()
    assert not result.composite[bad].any()
    table = find_point_sources(images)
    to_det, to_truth = match(table, truth)
    assert len(table) == len(truth) and to_det.max() < 0.5 and to_truth.max() < 0.5


def test_invalid_pixels_are_not_zeros_in_the_blur(scene):
    """Normalised convolution: a hole on the arc ridge barely changes the residual."""
    hole = np.s_[85:95, 96:106]  # on the ridge, between two sources
    a = scene["F150W"].copy()
    a[hole] = np.nan
    with_hole = PointSourceFilter()({"F150W": a, "F200W": scene["F200W"]})
    clean = PointSourceFilter()(scene)
    near = np.zeros(SHAPE, dtype=bool)
    near[80:100, 91:111] = True  # up to 5 px around the hole
    near[hole] = False
    diff = np.abs(with_hole.residuals["F150W"] - clean.residuals["F150W"])[near]
    # zero-filling the hole (what a plain blur does) would leave a bright rim
    zero = np.where(np.isfinite(a), a, 0.0)
    naive = np.maximum(zero - blur(zero, 5), 0.0)
    diff_naive = np.abs(naive - clean.residuals["F150W"])[near]
    assert np.median(diff_naive) > 10
    assert np.median(diff) < 5
    assert np.all(with_hole.residuals["F150W"][hole] == 0)
    assert not with_hole.candidates[hole].any()


def test_masked_array_input(scene):
    a = np.ma.masked_array(scene["F150W"], mask=np.zeros(SHAPE, dtype=bool))
    a.mask[0:10, 0:10] = True
    result = PointSourceFilter()([a, scene["F200W"]])
    assert not result.composite[0:10, 0:10].any()


def test_nddata_with_wcs_gives_sky_centroid(scene):
    wcs = make_wcs()
    images = {band: CCDData(scene[band], unit="MJy/sr", wcs=wcs) for band in BANDS}
    table = find_point_sources(images)
    assert table.colnames[:4] == ["id", "x_centroid", "y_centroid", "sky_centroid"]
    sky = table["sky_centroid"]
    assert isinstance(sky, SkyCoord)
    ref = wcs.pixel_to_world(table["x_centroid"], table["y_centroid"])
    assert np.all(sky.separation(ref).to_value(u.mas) < 1e-3)
    assert table["peak_F150W"].unit == u.MJy / u.sr
    # sky=False drops the column; an explicit wcs overrides the images' one
    assert "sky_centroid" not in find_point_sources(images, sky=False).colnames
    other = make_wcs()
    other.wcs.crval = [10.0, 20.0]
    t2 = find_point_sources({band: NDData(scene[band], wcs=wcs) for band in BANDS}, wcs=other)
    assert abs(t2["sky_centroid"][0].dec.deg - 20.0) < 0.01


def test_wcs_argument_with_plain_arrays(scene):
    table = find_point_sources(scene, wcs=make_wcs(), sky=True)
    assert "sky_centroid" in table.colnames
    assert "sky_centroid" not in find_point_sources(scene).colnames


def test_bands_in_different_units(scene):
    images = {
        "F150W": CCDData(scene["F150W"], unit="MJy/sr"),
        "F200W": CCDData(scene["F200W"] * 1000, unit="kJy/sr"),
    }
    result = PointSourceFilter()(images)
    ref = PointSourceFilter()(scene)
    np.testing.assert_array_equal(result.candidates, ref.candidates)
    np.testing.assert_allclose(result.normalized, ref.normalized, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(
        result.residuals["F200W"], 1000 * ref.residuals["F200W"], rtol=1e-9, atol=1e-9
    )
    assert result.unit == u.MJy / u.sr
    assert result.units["F200W"] == u.kJy / u.sr
    table = find_point_sources(images)
    assert table["peak_F200W"].unit == u.kJy / u.sr
    images["F200W"] = CCDData(scene["F200W"], unit="adu")
    with pytest.raises(ValueError, match=r"images\['F200W'\] has unit adu, which cannot"):
        PointSourceFilter()(images)


def test_quantity_and_integer_input(scene):
    q = {b: scene[b] * u.nJy for b in BANDS}
    result = PointSourceFilter()(q)
    assert result.unit == u.nJy
    ints = [np.round(scene[b] * 10).astype(np.int32) for b in BANDS]
    assert PointSourceFilter()(ints).candidates.any()


# ---------------------------------------------------------------------------
# nothing found
# ---------------------------------------------------------------------------


def test_nothing_found_returns_none_with_warning():
    arc_only = make_scene(sources=np.empty((0, 3)), seed=5)
    assert issubclass(NoDetectionsWarning, LensdualWarning)
    with pytest.warns(NoDetectionsWarning, match="no point-source candidate found"):
        assert find_point_sources(arc_only) is None
    assert not PointSourceFilter()(arc_only).candidates.any()


def test_min_pixels_can_remove_everything(scene):
    with pytest.warns(NoDetectionsWarning, match="min_pixels=500"):
        assert find_point_sources(scene, min_pixels=500) is None
    # no photutils warning leaks out
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        find_point_sources(scene, min_pixels=500)
    assert [w.category for w in caught] == [NoDetectionsWarning]


def test_connectivity_and_min_pixels(scene):
    t8 = find_point_sources(scene, min_pixels=2)
    t4 = find_point_sources(scene, connectivity=4)
    assert len(t8) <= 10 and len(t4) >= 10
    assert t8.meta["min_pixels"] == 2 and t4.meta["connectivity"] == 4


# ---------------------------------------------------------------------------
# bad input
# ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "exc", "msg"),
    [
        ({"smooth_sigma": 0}, ValueError, "smooth_sigma must be > 0"),
        ({"smooth_sigma": -2.0}, ValueError, "smooth_sigma must be > 0"),
        ({"smooth_sigma": np.nan}, ValueError, "smooth_sigma must be finite"),
        ({"smooth_sigma": "5"}, TypeError, "smooth_sigma must be a real number"),
        ({"norm_sigma": 0}, ValueError, "norm_sigma must be > 0"),
        ({"threshold": -0.1}, ValueError, "threshold must be >= 0"),
        ({"threshold": None}, TypeError, "threshold must be a real number"),
        ({"threshold_factor": -1}, ValueError, "threshold_factor must be >= 0"),
        ({"min_snr": -1}, ValueError, "min_snr must be >= 0"),
        ({"min_snr": True}, TypeError, "min_snr must be a real number"),
    ],
)
def test_bad_parameters(kwargs, exc, msg):
    with pytest.raises(exc, match=msg):
        PointSourceFilter(**kwargs)


def test_parameters_and_repr():
    f = PointSourceFilter(smooth_sigma=4, threshold=0)
    assert f.smooth_sigma == 4.0 and f.threshold == 0.0 and f.min_snr == 5.0
    assert repr(f).startswith("PointSourceFilter(smooth_sigma=4.0")
    img = make_scene(seed=4)
    assert f(img).floor == 0.0


def test_bad_images(scene):
    a, b = scene["F150W"], scene["F200W"]
    f = PointSourceFilter()
    with pytest.raises(ValueError, match=r"same shape, got 'F150W': \(160, 200\), 'F200W'"):
        f({"F150W": a, "F200W": b[:, :-1]})
    with pytest.raises(ValueError, match="at least one band"):
        f({})
    with pytest.raises(ValueError, match="at least one band"):
        f([])
    with pytest.raises(ValueError, match=r"images\['1'\] has no valid pixel"):
        f([a, np.full(SHAPE, np.nan)])
    with pytest.raises(ValueError, match=r"images\['F200W'\] has no valid pixel"):
        f({"F150W": a, "F200W": NDData(b, mask=np.ones(SHAPE, dtype=bool))})
    with pytest.raises(ValueError, match=r"images\['0'\] must be a 2-D image, got shape"):
        f([np.stack([a, b])])
    with pytest.raises(ValueError, match=r"images\['0'\] is empty \(shape \(0, 5\)\)"):
        f([np.zeros((0, 5))])
    with pytest.raises(ValueError, match=r"the mask of images\['0'\] has shape \(3, 3\)"):
        f([NDData(a, mask=np.zeros((3, 3), dtype=bool))])
    with pytest.raises(TypeError, match="images must be a dict"):
        f(a)
    with pytest.raises(TypeError, match="images must be a dict"):
        f("F150W")
    with pytest.raises(TypeError, match=r"images\['0'\] must be a numpy array, NDData"):
        f([[[1.0, 2.0], [3.0, 4.0]]])
    with pytest.raises(TypeError, match=r"images\['0'\] must hold real numbers"):
        f([a.astype(complex)])
    with pytest.raises(TypeError, match=r"images\['0'\] must hold real numbers"):
        f([a > 0])
    with pytest.raises(TypeError, match=r"keys \(band names\) of images must be strings"):
        f({150: a})
    with pytest.raises(ValueError, match=r"keys \(band names\) of images must not be empty"):
        f({"": a})


def test_bad_find_arguments(scene):
    with pytest.raises(ValueError, match="sky=True needs a WCS"):
        find_point_sources(scene, sky=True)
    with pytest.raises(TypeError, match="sky must be True, False or None"):
        find_point_sources(scene, sky="yes")
    with pytest.raises(TypeError, match="filter must be a PointSourceFilter"):
        find_point_sources(scene, filter={"smooth_sigma": 5})
    with pytest.raises(TypeError, match="wcs must be an astropy WCS"):
        find_point_sources(scene, wcs="J2000")
    with pytest.raises(ValueError, match="min_pixels must be >= 1"):
        find_point_sources(scene, min_pixels=0)
    with pytest.raises(TypeError, match="min_pixels must be an integer"):
        find_point_sources(scene, min_pixels=2.5)
    with pytest.raises(ValueError, match="connectivity must be 4 or 8"):
        find_point_sources(scene, connectivity=6)
    with pytest.raises(ValueError, match="same shape"):
        find_point_sources([scene["F150W"], scene["F200W"][1:]])


def test_custom_filter_is_used(scene):
    f = PointSourceFilter(smooth_sigma=4, threshold=0.35)
    table = find_point_sources(scene, filter=f)
    assert table.meta["smooth_sigma"] == 4 and table.meta["threshold"] == 0.35


# ---------------------------------------------------------------------------
# messages that name the input and the fix
# ---------------------------------------------------------------------------


def test_sky_not_subtracted_is_named(scene):
    """A sky pedestal hides every source (the filter divides by the smoothed image): the
    warning says so and suggests background subtraction."""
    result = PointSourceFilter()(scene)
    assert all(result.low_levels[b] < 0 for b in BANDS)  # background-subtracted scene
    pedestal = {b: scene[b] + 1000.0 for b in BANDS}
    with pytest.warns(
        NoDetectionsWarning,
        match=r"no point-source candidate found .*sky \(background\) seems not to be "
        r"subtracted \(band 'F150W': 95 % of its pixels are above 99\d\.\d, \d+ times its "
        r"noise.*Subtract the background first",
    ):
        assert find_point_sources(pedestal) is None
    # the hint is only given when it applies
    arc_only = make_scene(sources=np.empty((0, 3)), seed=5)
    with pytest.warns(NoDetectionsWarning) as rec:
        find_point_sources(arc_only)
    assert "sky" not in str(rec[0].message)
    found = find_point_sources(scene)
    assert set(found.meta["low_levels"]) == set(BANDS)


def test_empty_bands_name_the_file_and_the_fix(scene):
    a = scene["F150W"]
    f = PointSourceFilter()
    nan = NDData(np.full(SHAPE, np.nan), meta={"FILENAME": "l1_f200w.fits"})
    with pytest.raises(
        ValueError,
        match=r"images\['F200W'\] has no valid pixel \(all NaN, infinite or masked\) \(file "
        r"l1_f200w\.fits\): all 32000 pixels are NaN or infinite\. Check that the right file",
    ):
        f({"F150W": a, "F200W": nan})
    from astropy.nddata import StdDevUncertainty

    zero_err = NDData(
        a,
        mask=np.ones(SHAPE, bool),
        uncertainty=StdDevUncertainty(np.zeros(SHAPE)),
        meta={"filename": "err0.fits"},
    )
    with pytest.raises(
        ValueError,
        match=r"images\['F200W'\] has no valid pixel .*\(file err0\.fits\): its mask is True "
        r"\(bad\) at every pixel, and its error map \(uncertainty\) is zero or NaN",
    ):
        f({"F150W": a, "F200W": zero_err})


def test_single_plane_cube_is_squeezed(scene):
    flat = PointSourceFilter()(scene)
    cube = {b: scene[b][None] for b in BANDS}
    with pytest.warns(LensdualWarning, match=r"has shape \(1, 160, 200\)") as rec:
        squeezed = PointSourceFilter()(cube)
    assert [str(w.message)[:17] for w in rec] == ["images['F150W'] h", "images['F200W'] h"]
    np.testing.assert_array_equal(squeezed.candidates, flat.candidates)
    with pytest.raises(ValueError, match=r"got shape \(2, 160, 200\): a cube of 2 planes"):
        PointSourceFilter()([np.stack([scene["F150W"], scene["F200W"]])])


def test_float32_maps_agree_with_float64(scene):
    """float32 maps (the default of find_point_sources): the same detections."""
    f64 = PointSourceFilter()(scene)
    f32 = PointSourceFilter(dtype="float32")(scene)
    assert f32.normalized.dtype == np.float32 and f32.coadded.dtype == np.float32
    np.testing.assert_array_equal(f32.candidates, f64.candidates)
    for band in f64.bands:
        np.testing.assert_allclose(f32.residuals[band], f64.residuals[band], rtol=0, atol=1e-4)
        assert f32.means[band] == pytest.approx(f64.means[band], rel=1e-6)
        assert f32.noise[band] == pytest.approx(f64.noise[band], rel=1e-6)
    t32 = find_point_sources(scene)
    t64 = find_point_sources(scene, filter=PointSourceFilter())
    assert len(t32) == len(t64) > 0
    np.testing.assert_array_equal(t32["area"], t64["area"])
    np.testing.assert_allclose(t32["x_centroid"], t64["x_centroid"], atol=1e-5)
    np.testing.assert_allclose(t32["y_centroid"], t64["y_centroid"], atol=1e-5)
    # with invalid pixels (the normalised-convolution branch)
    masked = {b: np.where(np.arange(scene[b].shape[1]) < 7, np.nan, scene[b]) for b in scene}
    np.testing.assert_array_equal(
        PointSourceFilter(dtype="float32")(masked).candidates,
        PointSourceFilter()(masked).candidates,
    )
    with pytest.raises(ValueError, match="dtype"):
        PointSourceFilter(dtype="int32")

"""Point-source candidates on a lens arc: the filter chain of the paper's Appendix C."""

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime

import numpy as np
from astropy import units as u
from astropy.table import QTable
from astropy.wcs.wcsapi import BaseHighLevelWCS, BaseLowLevelWCS, HighLevelWCSWrapper
from scipy.ndimage import gaussian_filter

from .._validation import as_int, as_real, split_image
from ..exceptions import NoDetectionsWarning
from . import _kernels

__all__ = ["PointSourceFilter", "PointSourceMap", "find_point_sources"]

# Gaussian blurs: scipy's defaults, spelled out because the results depend on them.
_BLUR_MODE = "reflect"
_BLUR_TRUNCATE = 4.0

# MAD -> standard deviation of a Gaussian.
_MAD_TO_SIGMA = 1.482602218505602

# The noise of each residual is estimated on a regular sub-grid of about this
# many pixels (every k-th pixel in both directions).
_NOISE_SAMPLE = 2**18

_DUMMY_F = np.zeros((1, 1))
_DUMMY_F32 = np.zeros((1, 1), dtype=np.float32)
_DUMMY_B = np.zeros((1, 1), dtype=bool)
_DUMMY_B.flags.writeable = False


def _readonly(array):
    """A read-only view: the kernels then see one array type whatever the inputs are."""
    view = array.view()
    view.flags.writeable = False
    return view


@dataclass(kw_only=True, eq=False, repr=False, frozen=True)
class PointSourceMap:
    """Output of :class:`PointSourceFilter`: the candidate map and its ingredients.

    All maps have the common shape of the input bands. Instances are created
    by :class:`PointSourceFilter`; the arrays are fresh (never views of the
    inputs) and may be modified by the caller. Every parameter is also an
    attribute of the same name.

    Parameters
    ----------
    bands : tuple of str
        Band names, in input order (``"0"``, ``"1"``, ... for a sequence).
    candidates : `~numpy.ndarray` of bool
        The point-source candidate map: ``normalized > threshold`` (and the
        co-added residual above the noise floor, see
        :class:`PointSourceFilter`).
    normalized : `~numpy.ndarray` of float (the filter's dtype)
        The co-added masked residual divided by the smoothed co-added raw
        image (0 outside the composite mask).
    coadded : `~numpy.ndarray` of float
        The co-added residual of all bands inside the composite mask, 0
        elsewhere (in the unit of the first band that has one).
    residuals : dict of str to `~numpy.ndarray`
        Per band, the "first filtered image": ``max(image - smoothed, 0)``,
        0 at invalid (NaN or masked) pixels, in that band's own unit.
    means : dict of str to float
        Per band, the mean of the first filtered image over its valid pixels.
    flag_levels : dict of str to float
        Per band, ``threshold_factor * means[band]``: the pixels strictly
        above it are flagged.
    noise : dict of str to float
        Per band, the Gaussian-equivalent standard deviation of the residual
        ``image - smoothed`` (1.4826 times its median absolute deviation on
        a regular sub-grid of about 2**18 valid pixels).
    low_levels : dict of str to float
        Per band, the 5th percentile of the valid pixels on the same
        sub-grid, in the band's unit: about the sky level minus 1.6 sigma on
        a background-subtracted image (so about 0 or below). Far above
        ``noise`` it says that the sky was not subtracted (see
        :func:`find_point_sources`).
    floor : float
        Lower bound applied to the normalising image (co-add unit).
    snr_level : float
        Level the co-added residual of a candidate must exceed (co-add unit).
    units : dict of str to `~astropy.units.Unit` or None
        Per band, the unit of the input image (None when it had none).
    unit : `~astropy.units.Unit` or None
        The co-add unit: that of the first band that has one.
    wcs : WCS or None
        The WCS of the first band that has one.
    """

    bands: tuple
    candidates: np.ndarray
    normalized: np.ndarray
    coadded: np.ndarray
    residuals: dict
    means: dict
    flag_levels: dict
    noise: dict
    floor: float
    snr_level: float
    units: dict
    unit: object
    wcs: object
    low_levels: dict = field(default_factory=dict)

    @property
    def shape(self):
        """Common shape of the maps."""
        return self.candidates.shape

    @property
    def flags(self):
        """dict of str to bool `~numpy.ndarray`: per band, the flagged pixels."""
        return {b: self.residuals[b] > self.flag_levels[b] for b in self.bands}

    @property
    def composite(self):
        """bool `~numpy.ndarray`: the pixels flagged in every band."""
        flags = self.flags
        out = flags[self.bands[0]].copy()
        for b in self.bands[1:]:
            out &= flags[b]
        return out

    def __repr__(self):
        return (
            f"<PointSourceMap bands={list(self.bands)} shape={self.shape} "
            f"candidate_pixels={int(np.count_nonzero(self.candidates))}>"
        )


def _unpack(image, band):
    """Return (float64 data, valid map or None, unit or None, wcs or None)."""
    from ..photometry._inputs import file_of, squeeze_plane

    name = f"images[{band!r}]"
    path = file_of(image)
    in_file = "" if path is None else f" (file {path})"
    image = squeeze_plane(image, name)
    data, mask, unit, wcs, unc = split_image(image, name)
    if data.size == 0:
        raise ValueError(f"images[{band!r}] is empty (shape {data.shape})")
    if mask is not None:
        if mask.ndim == 0:
            mask = np.broadcast_to(mask, data.shape)
        if mask.shape != data.shape:
            raise ValueError(
                f"the mask of images[{band!r}] has shape {mask.shape}, "
                f"the image has shape {data.shape}"
            )
        mask = mask.astype(bool, copy=False)
        if not mask.any():
            mask = None
    # native-endian, C-contiguous float64; a copy only where the input is not
    data = _readonly(np.ascontiguousarray(data, dtype=np.float64))
    valid = None
    if _kernels.has_nonfinite(data):
        valid = np.isfinite(data)
    if mask is not None:
        valid = ~mask if valid is None else valid & ~mask
    if valid is not None:
        if not valid.any():
            text = f"{name} has no valid pixel (all NaN, infinite or masked){in_file}: "
            if not np.isfinite(data).any():
                text += (
                    f"all {data.size} pixels are NaN or infinite. Check that the right file and "
                    "extension (e.g. SCI) are read and that the cut-out overlaps the exposed data"
                )
            else:
                text += "its mask is True (bad) at every pixel"
                err = None if unc is None else np.asarray(unc.array, dtype=np.float64)
                if err is not None and not (np.isfinite(err) & (err > 0)).any():
                    text += (
                        ", and its error map (uncertainty) is zero or NaN at every pixel: "
                        "check the error file and extension (e.g. ERR), give a weight map "
                        "instead, or no error map at all"
                    )
            raise ValueError(text)
        valid = _readonly(np.ascontiguousarray(valid))
    if wcs is not None and not isinstance(wcs, BaseHighLevelWCS):
        wcs = HighLevelWCSWrapper(wcs) if isinstance(wcs, BaseLowLevelWCS) else None
    return data, valid, unit, wcs


def _collect(images):
    """Validate ``images``; return band names and a list of unpacked bands."""
    if isinstance(images, Mapping):
        names = list(images)
        for name in names:
            if not isinstance(name, str):
                raise TypeError(f"the keys (band names) of images must be strings, got {name!r}")
            if not name:
                raise ValueError("the keys (band names) of images must not be empty strings")
        items = [images[name] for name in names]
    elif isinstance(images, Sequence) and not isinstance(images, (str, bytes)):
        names = [str(k) for k in range(len(images))]
        items = list(images)
    else:
        raise TypeError(
            "images must be a dict {band: image} or a list/tuple of images "
            f"(wrap a single image in a list), got {type(images).__name__}"
        )
    if not items:
        raise ValueError("images must hold at least one band, got none")
    bands = [_unpack(image, name) for name, image in zip(names, items, strict=True)]
    shapes = [b[0].shape for b in bands]
    if len(set(shapes)) > 1:
        desc = ", ".join(f"{n!r}: {s}" for n, s in zip(names, shapes, strict=True))
        raise ValueError(f"all bands of images must have the same shape, got {desc}")
    return names, bands


def _common_unit(names, bands):
    """Scale factors that bring every band to the unit of the first band with one."""
    units = [b[2] for b in bands]
    ref = next((unit for unit in units if unit is not None), None)
    scales = []
    for name, unit in zip(names, units, strict=True):
        if unit is None or ref is None:
            scales.append(1.0)
            continue
        try:
            scales.append(float(unit.to(ref)))
        except u.UnitsError:
            raise ValueError(
                f"images[{name!r}] has unit {unit!s}, which cannot be converted to the "
                f"unit {ref!s} of the other bands"
            ) from None
    return ref, scales


def _noise_stride(shape):
    """Step of the regular sub-grid on which the residual noise is estimated."""
    return max(1, int((shape[0] * shape[1] / _NOISE_SAMPLE) ** 0.5))


def _residual_noise(data, num, wblur, valid, stride):
    """Gaussian-equivalent sigma (1.4826 MAD) of ``data - smoothed`` on a sub-grid."""
    sub = (slice(None, None, stride), slice(None, None, stride))
    if valid is None:
        r = data[sub] - num[sub]
    else:
        v = valid[sub]
        r = data[sub][v] - num[sub][v] / wblur[sub][v]
    if r.size == 0:  # the valid pixels all fall between the sub-grid nodes
        return _residual_noise(data, num, wblur, valid, 1)
    return _MAD_TO_SIGMA * float(np.median(np.abs(r - np.median(r))))


def _low_level(data, valid, stride):
    """5th percentile of the valid pixels on the noise sub-grid."""
    sub = (slice(None, None, stride), slice(None, None, stride))
    v = data[sub] if valid is None else data[sub][valid[sub]]
    if v.size == 0:
        v = data if valid is None else data[valid]
    return float(np.percentile(v, 5.0))


#: A band whose 5th-percentile pixel is this many noise sigmas above 0 looks
#: like an image whose sky was not subtracted.
_SKY_SIGMAS = 10.0


def _sky_hint(result):
    """Words on the bands whose sky seems not subtracted ("" when none)."""
    out = []
    for band in result.bands:
        low, noise = result.low_levels.get(band), result.noise.get(band)
        if low is None or noise is None or not noise > 0:
            continue
        if low > _SKY_SIGMAS * noise:
            unit = result.units.get(band)
            u_txt = "" if unit is None else f" {unit}"
            out.append(
                f"band {band!r}: 95 % of its pixels are above {low:.4g}{u_txt}, "
                f"{low / noise:.0f} times its noise ({noise:.3g}{u_txt})"
            )
    if not out:
        return ""
    return (
        "; the sky (background) seems not to be subtracted ("
        + "; ".join(out)
        + "): the filter divides by the smoothed image, so a sky pedestal hides every point "
        "source. Subtract the background first (e.g. photutils.background.Background2D, or "
        "the pipeline's sky-subtracted product)"
    )


def _blur(image, sigma, dtype=np.float64):
    return gaussian_filter(image, sigma, output=dtype, mode=_BLUR_MODE, truncate=_BLUR_TRUNCATE)


class PointSourceFilter:
    r"""The point-source filter chain of the paper's Appendix C.

    Point sources (compact star clusters) on a bright, smooth lens arc are
    picked out band by band with a Gaussian high-pass filter, kept where they
    stand out in every band, and normalised by the local arc brightness.

    Parameters
    ----------
    smooth_sigma : float, optional
        Standard deviation, in pixels, of the Gaussian whose smoothed image is
        subtracted from each band (paper: 5). Must be > 0.
    threshold_factor : float, optional
        A pixel is flagged in a band when its positive residual exceeds
        ``threshold_factor`` times the band's mean positive residual (paper:
        3). Must be >= 0.
    norm_sigma : float, optional
        Standard deviation, in pixels, of the Gaussian that smooths the
        co-added raw image used for the normalisation (paper: 3). Must be > 0.
    threshold : float, optional
        A pixel is a candidate when the normalised map exceeds it (paper:
        0.3). Must be >= 0.
    min_snr : float, optional
        Noise floor, an extension of the paper (see Notes): a candidate's
        co-added residual must also exceed ``min_snr`` times the noise of the
        co-added residual, and the normalising image is bounded below by
        ``min_snr * noise / threshold``. Must be >= 0; 0 gives the paper's
        chain unchanged.
    dtype : {"float64", "float32"}, optional
        Data type of the maps (blurs, residuals, co-add, normalised map).
        The kernels compute every pixel in float64 and sum the band means in
        float64 whatever it is; "float32" only rounds the stored blurs and
        outputs to a relative 6e-8, far below the noise of any image, and
        halves the memory of the chain (about 2 + n_bands image-sized maps
        alive at once). A pixel within that rounding of a threshold may flip;
        the candidates of the test scenes are the same. Default "float64"
        (bit-for-bit the documented chain); :func:`find_point_sources` uses
        "float32" unless given a filter.

    Notes
    -----
    For each band :math:`I_b` (data :math:`d`, validity :math:`w`: finite and
    not masked) the chain is

    1. :math:`S_b = G_{\sigma_s} * I_b` (:math:`\sigma_s` = ``smooth_sigma``),
       computed as the normalised convolution :math:`G(d w) / G(w)` when the
       band has invalid pixels, so that NaN or masked pixels do not leak into
       the blur (a band without any is blurred directly). The blurs are
       `scipy.ndimage.gaussian_filter` with ``mode="reflect"`` and
       ``truncate=4``.
    2. The first filtered image :math:`R_b = \max(I_b - S_b, 0)`, 0 at invalid
       pixels. **Sign:** the paper writes "the raw image is subtracted from
       the smoothed image", which would make point sources negative and then
       drop them with "keeping only the positive values"; we use
       ``image - smoothed``, in which point sources are positive.
    3. :math:`m_b` is the mean of :math:`R_b` over the valid pixels of the
       band (zeros included: the mean of "this first filtered image"); the
       pixels with :math:`R_b > f\,m_b` (strictly; :math:`f` =
       ``threshold_factor``) are flagged.
    4. The composite mask :math:`M` keeps the pixels flagged in every band
       (so invalid pixels in any band are never in it, nor candidates).
    5. The co-added masked residual :math:`C = M \sum_b R_b`.
    6. **Normalising image:** the paper smooths "the raw image" with
       :math:`\sigma_n` = ``norm_sigma`` = 3; with several bands we smooth
       the co-added raw image :math:`\sum_b I_b` (the same sum as the
       numerator, so that the ratio does not scale with the number of
       bands), again by normalised convolution over the pixels valid in
       every band.
       :math:`N = C / \max(G_{\sigma_n} * \sum_b I_b,\; F)`, 0 where that
       denominator is not positive and outside :math:`M`.
    7. Candidates: :math:`N > t` and :math:`C > s\,\sigma_C`.

    **Noise floor (extension).** On background-subtracted images the
    smoothed raw image is close to 0, and of random sign, away from the arc,
    so the ratio of step 6 explodes on noise there: the paper's chain relies
    on cut-outs dominated by the arc. We bound the denominator below by
    :math:`F = s\,\sigma_C / t` and require :math:`C > s\,\sigma_C`
    (:math:`s` = ``min_snr``, :math:`t` = ``threshold``), where
    :math:`\sigma_C = (\sum_b \sigma_b^2)^{1/2}` is the noise of the co-added
    residual and :math:`\sigma_b` is 1.4826 times the median absolute
    deviation of :math:`I_b - S_b` (the residual before clipping) over the
    valid pixels of a regular sub-grid (every :math:`k`-th pixel in both
    directions, :math:`k` chosen for about :math:`2^{18}` pixels). The point
    sources hardly move the median; the residual ridge of an arc that covers
    much of the image inflates it somewhat, which makes the floor stricter.
    On the arc, where the smoothed image exceeds :math:`F`, the paper's
    criterion is unchanged; in the background a candidate has to be an
    :math:`s`-sigma peak of the co-added residual. ``min_snr=0`` switches
    the floor off (pixels where the smoothed image is not positive are then
    never candidates).

    Bands with different units are converted to the unit of the first band
    that has one before co-adding; plain arrays are assumed to be in that
    unit. The uncertainty of NDData inputs is not used (the paper's chain
    does not use one).

    Speed: after the Gaussian blurs (one per band plus one, doubled for
    bands with invalid pixels) everything runs in two compiled passes over
    the image: one accumulates the per-band means and the co-added raw image,
    the other does steps 2-7.

    Raises
    ------
    TypeError
        A parameter is not a real number.
    ValueError
        A parameter is not finite or out of its range.

    Examples
    --------
    >>> import numpy as np
    >>> from lensdual.detection import PointSourceFilter
    >>> y, x = np.mgrid[:64, :64]
    >>> arc = 50 * np.exp(-0.5 * ((y - 32) / 10) ** 2)
    >>> star = 20 * np.exp(-0.5 * ((x - 20) ** 2 + (y - 30) ** 2) / 0.85**2)
    >>> result = PointSourceFilter()({"F150W": arc + star, "F200W": arc + star})
    >>> [tuple(int(v) for v in p) for p in np.argwhere(result.candidates)]
    [(30, 20)]
    """

    def __init__(
        self,
        smooth_sigma=5,
        threshold_factor=3.0,
        norm_sigma=3,
        threshold=0.3,
        *,
        min_snr=5.0,
        dtype="float64",
    ):
        self.smooth_sigma = as_real(smooth_sigma, "smooth_sigma", minimum=0, inclusive=False)
        self.threshold_factor = as_real(threshold_factor, "threshold_factor", minimum=0)
        self.norm_sigma = as_real(norm_sigma, "norm_sigma", minimum=0, inclusive=False)
        self.threshold = as_real(threshold, "threshold", minimum=0)
        self.min_snr = as_real(min_snr, "min_snr", minimum=0)
        try:
            self.dtype = np.dtype(dtype)
        except TypeError:
            self.dtype = None
        if self.dtype not in (np.float64, np.float32):
            raise ValueError(f"dtype must be 'float64' or 'float32', got {dtype!r}")

    def __repr__(self):
        return (
            f"PointSourceFilter(smooth_sigma={self.smooth_sigma}, "
            f"threshold_factor={self.threshold_factor}, norm_sigma={self.norm_sigma}, "
            f"threshold={self.threshold}, min_snr={self.min_snr}"
            + ("" if self.dtype == np.float64 else f", dtype='{self.dtype}'")
            + ")"
        )

    def __call__(self, images):
        """Run the filter chain on one or several bands.

        Parameters
        ----------
        images : dict of str to image, or sequence of images
            The bands, each a 2-D `~numpy.ndarray` (NaN pixels are invalid; a
            `~numpy.ma.MaskedArray` or `~astropy.units.Quantity` is
            understood), `~astropy.nddata.NDData` or
            `~astropy.nddata.CCDData` (``mask`` True pixels are invalid). All
            bands must have the same shape. A sequence names its bands
            ``"0"``, ``"1"``, ... The inputs are not modified.

        Returns
        -------
        result : `PointSourceMap`

        Raises
        ------
        TypeError
            ``images`` is not a dict or sequence, a band is not an array or
            NDData, holds non-real numbers, or a band name is not a string.
        ValueError
            No band, a band that is not 2-D or has no valid pixel, bands of
            different shapes, or incompatible units.
        """
        names, bands = _collect(images)
        nb = len(bands)
        ref_unit, scales = _common_unit(names, bands)
        # The maps (blurs, then the outputs written over them) are of self.dtype;
        # the kernels compute in float64 whatever it is.
        dtype = self.dtype
        dummy_f = _DUMMY_F if dtype == np.float64 else _DUMMY_F32
        datas, valids, nums, wblurs = [], [], [], []
        masked = np.zeros(nb, dtype=bool)
        for k, (data, valid, _, _) in enumerate(bands):
            if scales[k] != 1.0:
                data = _readonly(data * scales[k])
            datas.append(data)
            if valid is None:
                valids.append(_DUMMY_B)
                wblurs.append(dummy_f)
                nums.append(_blur(data, self.smooth_sigma, dtype))
            else:
                masked[k] = True
                valids.append(valid)
                nums.append(_blur(np.where(valid, data, 0.0), self.smooth_sigma, dtype))
                wblurs.append(_blur(valid.astype(dtype), self.smooth_sigma, dtype))
        datas, valids, nums, wblurs = (tuple(v) for v in (datas, valids, nums, wblurs))
        any_masked = bool(masked.any())
        shape = datas[0].shape

        coadd = np.empty(shape, dtype=dtype)
        wcommon = np.empty(shape, dtype=dtype) if any_masked else dummy_f
        pos_sum, count = _kernels.band_statistics(
            datas, nums, wblurs, valids, masked, any_masked, coadd, wcommon
        )
        norm_num = _blur(coadd, self.norm_sigma, dtype)
        norm_w = _blur(wcommon, self.norm_sigma, dtype) if any_masked else dummy_f
        del wcommon

        means = pos_sum / count
        flag_levels = self.threshold_factor * means
        stride = _noise_stride(shape)
        sigmas = np.array(
            [
                _residual_noise(
                    datas[k], nums[k], wblurs[k], valids[k] if masked[k] else None, stride
                )
                for k in range(nb)
            ]
        )
        lows = np.array(
            [_low_level(datas[k], valids[k] if masked[k] else None, stride) for k in range(nb)]
        )
        sigma_coadd = float(np.sqrt(np.sum(sigmas**2)))
        snr_level = self.min_snr * sigma_coadd
        floor = snr_level / self.threshold if self.threshold > 0 else 0.0

        # The outputs reuse the buffers this call allocated and no longer needs
        # (the kernel allows it): residuals overwrite the blurs of the bands,
        # the co-add overwrites its normalising blur, the normalised map the
        # co-added raw image. This saves ~5 fresh image-sized allocations.
        residuals = nums
        coadded = norm_num
        normalized = coadd
        candidates = np.empty(shape, dtype=bool)
        _kernels.filter_pixels(
            datas,
            nums,
            wblurs,
            valids,
            masked,
            flag_levels,
            norm_num,
            norm_w,
            any_masked,
            floor,
            snr_level,
            self.threshold,
            residuals,
            coadded,
            normalized,
            candidates,
        )

        # per-band quantities go back to the band's own unit
        back = [1.0 / s for s in scales]
        residuals = list(residuals)
        for k in range(nb):
            if back[k] != 1.0:
                residuals[k] *= back[k]
        wcs = next((b[3] for b in bands if b[3] is not None), None)
        return PointSourceMap(
            bands=tuple(names),
            candidates=candidates,
            normalized=normalized,
            coadded=coadded,
            residuals=dict(zip(names, residuals, strict=True)),
            means={n: float(means[k] * back[k]) for k, n in enumerate(names)},
            flag_levels={n: float(flag_levels[k] * back[k]) for k, n in enumerate(names)},
            noise={n: float(sigmas[k] * back[k]) for k, n in enumerate(names)},
            low_levels={n: float(lows[k] * back[k]) for k, n in enumerate(names)},
            floor=float(floor),
            snr_level=float(snr_level),
            units={n: b[2] for n, b in zip(names, bands, strict=True)},
            unit=ref_unit,
            wcs=wcs,
        )


def _as_wcs(wcs):
    if wcs is None or isinstance(wcs, BaseHighLevelWCS):
        return wcs
    if isinstance(wcs, BaseLowLevelWCS):
        return HighLevelWCSWrapper(wcs)
    raise TypeError(
        f"wcs must be an astropy WCS (APE 14 high- or low-level interface) or None, "
        f"got {type(wcs).__name__}"
    )


def _segment_peaks(image, segm):
    """Maximum of ``image`` over each segment of ``segm``, in label order."""
    out = np.empty(segm.n_labels)
    data = segm.data
    for k, (label, slc) in enumerate(zip(segm.labels, segm.slices, strict=True)):
        out[k] = image[slc][data[slc] == label].max()
    return out


def _versions():
    import astropy
    import numba
    import photutils
    import scipy

    from .. import __version__

    return {
        "lensdual": __version__,
        "photutils": photutils.__version__,
        "astropy": astropy.__version__,
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "numba": numba.__version__,
    }


def find_point_sources(images, *, filter=None, wcs=None, sky=None, min_pixels=1, connectivity=8):
    """Catalogue the point-source candidates of the Appendix C filter chain.

    The candidate map of :class:`PointSourceFilter` is segmented into
    connected regions (`photutils.segmentation.detect_sources`), and each
    region is measured with `photutils.segmentation.SourceCatalog`.

    Parameters
    ----------
    images : dict of str to image, or sequence of images
        The bands, as for :meth:`PointSourceFilter.__call__`.
    filter : `PointSourceFilter`, optional
        The filter to run; default ``PointSourceFilter(dtype="float32")``
        (the paper's parameters, with float32 maps: half the memory of
        float64 maps on a full frame, see :class:`PointSourceFilter`).
    wcs : WCS, optional
        World coordinate system of the images (any APE 14 WCS, e.g.
        `astropy.wcs.WCS`). Default: the WCS of the first band (NDData or
        CCDData) that has one.
    sky : bool or None, optional
        Whether to add the ``sky_centroid`` column. None (default): when a WCS
        is available. True without any WCS raises ValueError.
    min_pixels : int, optional
        Smallest number of connected candidate pixels that makes a source
        (>= 1).
    connectivity : {8, 4}, optional
        Pixel connectivity of the segmentation.

    Returns
    -------
    table : `~astropy.table.QTable` or None
        One row per source, or None (with a
        `~lensdual.exceptions.NoDetectionsWarning`) when there is none.
        Columns:

        * ``id``: 1, 2, ... (the segment labels);
        * ``x_centroid``, ``y_centroid``: centroid in 0-based pixel
          coordinates, weighted by the co-added masked residual
          (`PointSourceMap.coadded`) over the segment (it has the
          symmetry of the point source; the normalised map carries the
          gradient of the arc in its denominator);
        * ``sky_centroid``: `~astropy.coordinates.SkyCoord` of the centroid
          (only with a WCS);
        * ``peak``: peak of the normalised map over the segment;
        * ``area``: segment area (``pix2``);
        * ``peak_<band>``: per band, the peak of the positive residual
          (first filtered image) over the segment, in the band's unit.

        ``meta`` records the filter parameters, the per-band means, flag
        levels and noise, the noise floor, the segmentation settings, the
        date and the package versions.

    Raises
    ------
    TypeError
        Wrong type of ``filter``, ``wcs``, ``sky``, ``min_pixels`` or of the
        images (see :meth:`PointSourceFilter.__call__`).
    ValueError
        ``sky=True`` and no WCS, ``min_pixels < 1``, ``connectivity`` not 4
        or 8, or bad images.
    """
    from photutils.segmentation import SourceCatalog, detect_sources
    from photutils.utils.exceptions import NoDetectionsWarning as PhotutilsNoDetections

    if filter is None:
        filter = PointSourceFilter(dtype="float32")
    elif not isinstance(filter, PointSourceFilter):
        raise TypeError(f"filter must be a PointSourceFilter or None, got {type(filter).__name__}")
    wcs = _as_wcs(wcs)
    if sky is not None and not isinstance(sky, (bool, np.bool_)):
        raise TypeError(f"sky must be True, False or None, got {sky!r}")
    min_pixels = as_int(min_pixels, "min_pixels", minimum=1)
    if isinstance(connectivity, bool) or connectivity not in (4, 8):
        raise ValueError(f"connectivity must be 4 or 8, got {connectivity!r}")

    result = filter(images)
    if wcs is None:
        wcs = result.wcs
    if sky and wcs is None:
        raise ValueError(
            "sky=True needs a WCS: pass wcs= or images (NDData/CCDData) that carry one"
        )
    with_sky = wcs is not None if sky is None else bool(sky)

    segm = None
    if result.candidates.any():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", PhotutilsNoDetections)
            segm = detect_sources(
                result.candidates.view(np.uint8), 0.5, min_pixels, connectivity=connectivity
            )
    if segm is None:
        warnings.warn(
            f"no point-source candidate found (bands {list(result.bands)}, "
            f"{int(np.count_nonzero(result.candidates))} candidate pixels, "
            f"min_pixels={min_pixels})" + _sky_hint(result),
            NoDetectionsWarning,
            stacklevel=2,
        )
        return None

    if not segm.is_consecutive:
        segm.relabel_consecutive()
    cat = SourceCatalog(result.coadded, segm, wcs=wcs if with_sky else None)
    table = QTable()
    table["id"] = np.asarray(segm.labels, dtype=np.int64)
    table["x_centroid"] = np.asarray(cat.x_centroid, dtype=np.float64)
    table["y_centroid"] = np.asarray(cat.y_centroid, dtype=np.float64)
    if with_sky:
        table["sky_centroid"] = cat.sky_centroid
    table["peak"] = _segment_peaks(result.normalized, segm)
    table["area"] = cat.area
    for band in result.bands:
        peaks = _segment_peaks(result.residuals[band], segm)
        unit = result.units[band]
        table[f"peak_{band}"] = peaks if unit is None else peaks * unit

    table.meta["date"] = datetime.now(UTC).isoformat(timespec="seconds")
    table.meta["version"] = _versions()
    table.meta["bands"] = list(result.bands)
    for name in ("smooth_sigma", "threshold_factor", "norm_sigma", "threshold", "min_snr"):
        table.meta[name] = getattr(filter, name)
    table.meta["means"] = dict(result.means)
    table.meta["flag_levels"] = dict(result.flag_levels)
    table.meta["noise"] = dict(result.noise)
    table.meta["low_levels"] = dict(result.low_levels)
    table.meta["floor"] = result.floor
    table.meta["snr_level"] = result.snr_level
    table.meta["dtype"] = str(filter.dtype)
    table.meta["min_pixels"] = min_pixels
    table.meta["connectivity"] = connectivity
    table.meta["centroid_weights"] = "coadded masked residual"
    return table

"""PSF photometry of the point sources of one image: :class:`ArcPSFPhotometry`.

:class:`ArcPSFPhotometry` is set up (and its settings checked) once and then
called on images; :func:`psf_photometry` is the same in one call, as
astropy's `~astropy.stats.SigmaClip` and `~astropy.stats.sigma_clip`. The
work lives in the modules beside this one: the PSF profiles
(``_profiles``), the background bases (``_background``), the input handling
(``_inputs``) and the fits (``_fitting``).
"""

import textwrap
import warnings

import numpy as np
from astropy.coordinates import SkyCoord
from astropy.table import QTable

from .._validation import as_int, as_real
from ..exceptions import LensdualWarning
from ._background import _DEFAULT_BACKGROUND, _STRATEGY, BACKGROUND_STRATEGIES, _make_basis
from ._filters import _highpass, _reach
from ._fitting import _RESULT_COLUMNS, _estimate_fwhm, _Scene, _SourceFitter
from ._flags import _BAD_FLAGS, PhotometryFlag, describe_flags
from ._inputs import (
    _as_oversampling,
    _fit_shape,
    _outside_text,
    _positions,
    _psf_in_pixels,
    _psf_spec,
    _split_parts,
    _unpack_image,
)
from ._profiles import _GaussianProfile, _image_fwhm, _ImageProfile
from ._resolved import RESOLVED_COLUMNS, refit_resolved

__all__ = ["ArcPSFPhotometry", "psf_photometry"]

#: A PSF image whose FWHM differs from that of the sources by more than this
#: factor is refused (too wide) or warned about (too narrow); see _check_image_psf.
_PSF_WIDTH_TOLERANCE = 1.8
_PSF_CHECK_SOURCES = 6

#: psf_photometry works on a cut-out about the positions when its area is at most
#: this fraction of the image's (else on the whole image: the saving is small).
_CUTOUT_MAX_FRACTION = 0.5

#: What the photometry can model: point sources, or slightly resolved ones.
SOURCE_MODELS = ("point", "resolved")

_RESOLVED_ADVICE = (
    "the fluxes assume point sources and miss the light of resolved sources beyond the "
    "PSF, differently on differently stretched images (a flux-ratio bias). Check the "
    "PSF's pixel scale; for resolved sources (star clusters stretched along an arc) use "
    "source_model='resolved', which fits the PSF convolved with an elliptical Gaussian "
    "and reports each source's size"
)


def _cutout_margin(basis_kind, fit_shape, fwhm, highpass, local_est):
    """Pixels about the positions that the photometry reads, or None (unknown reach).

    A fit reads the pixels of its ``fit_shape`` box (and the models of the other
    sources, added as stamps, only there). The high-pass image (``"residual"``
    strategies) reads ``_reach(smooth_sigma)`` pixels further; the local
    background annulus ``outer_radius``; the arc direction of the ``"ridge"``
    background, taken at a box centre, the chain of blurs of `_make_basis`
    (source discs filled with sigma ``r``, gradient, structure tensor). Beyond
    that margin the data do not enter any result, and blurs with the image edge
    inside it are the same whether the edge is the image's or the cut-out's.
    """
    half = max(fit_shape) // 2
    reach = half
    if basis_kind == "ridge":
        r = max(2.0, 1.5 * fwhm)
        reach = half + 1 + _reach(r) + _reach(max(1.0, 0.6 * fwhm)) + _reach(max(2.0, 1.6 * fwhm))
    elif local_est is not None:
        outer = getattr(local_est, "outer_radius", None)
        if outer is None or not np.isfinite(outer):
            return None
        reach = max(half, int(np.ceil(float(outer))) + 1)
    if highpass:
        reach += _reach(highpass)
    return reach + 2


def _cutout_box(x, y, shape, margin):
    """Slices (rows, columns) of the bounding box of (x, y) plus ``margin``, or None.

    None when there is no position, the margin is unknown or the box would
    cover more than ``_CUTOUT_MAX_FRACTION`` of the image.
    """
    if margin is None or x.size == 0:
        return None
    ny, nx = shape
    x0 = max(int(np.floor(np.min(x))) - margin, 0)
    x1 = min(int(np.ceil(np.max(x))) + margin + 1, nx)
    y0 = max(int(np.floor(np.min(y))) - margin, 0)
    y1 = min(int(np.ceil(np.max(y))) + margin + 1, ny)
    if (x1 - x0) * (y1 - y0) > _CUTOUT_MAX_FRACTION * nx * ny:
        return None
    return (slice(y0, y1), slice(x0, x1))


class _ImageReader:
    """Reads one image on a cut-out about the positions, or whole.

    The photometry reads the image only in boxes about the positions (and,
    for the high-pass image and the arc direction of the ridge background,
    through blurs of known reach about them): it runs on the bounding box of
    the positions plus that reach, so that nothing of the size of the whole
    image is allocated; the results are those on the whole image (see
    `_cutout_margin`).

    Parameters
    ----------
    image : NDData or array
        The image, as given.
    label : str or None
        How messages name it.
    parts : tuple
        Its parts, from `~lensdual.photometry._inputs._split_parts`.
    x, y : ndarray
        The pixel positions (on the image) of the sources to fit.
    highpass : float or None
        Sigma (pixels) of the high-pass filter of the fitted image, or None.
    """

    def __init__(self, image, label, parts, x, y, highpass):
        self.image, self.label, self.parts = image, label, parts
        self.x, self.y = x, y
        self.highpass = highpass
        self.shape = parts[1].shape

    def read(self, margin):
        """The fitted image on the cut-out for ``margin`` (or whole).

        Returns
        -------
        fitdata, invalid, error : ndarray or None
            The image to fit (high-pass filtered when asked), its invalid
            pixels and errors (see `~lensdual.photometry._inputs._unpack_image`).
        x, y : ndarray
            The positions in the cut-out's pixels.
        offset : (int, int)
            The cut-out's first column and row on the image.
        box : pair of slices or None
            The cut-out; None: the whole image.
        """
        box = _cutout_box(self.x, self.y, self.shape, margin)
        got = None
        if box is not None:
            try:
                got = _unpack_image(self.image, "image", self.label, box=box, parts=self.parts)
            except ValueError:  # e.g. no valid pixel there: the whole image decides
                box = None
        if box is None:
            got = _unpack_image(self.image, "image", self.label, parts=self.parts)
        data, invalid, error = got[:3]
        offset = (0, 0) if box is None else (box[1].start, box[0].start)
        fitdata = _highpass(data, invalid, self.highpass) if self.highpass else data
        return fitdata, invalid, error, self.x - offset[0], self.y - offset[1], offset, box


# Docstring parts shared by ArcPSFPhotometry, its __call__ and psf_photometry:
# one text each, put in place of the "@name@" lines by _fill_doc.
_DOC_PARTS = {
    "image_positions": r"""
image : `~astropy.nddata.CCDData`, `~astropy.nddata.NDData` or array
    The image (a `~numpy.ndarray`, masked array or `~astropy.units.Quantity`
    is accepted too). An NDData's ``mask`` (True = bad), ``uncertainty``
    (`~astropy.nddata.StdDevUncertainty`, or a variance / inverse
    variance, used as the 1-sigma pixel errors that weight the fit),
    ``unit`` and ``wcs`` are used; NaN and infinite pixels, and pixels
    whose error is not positive, are ignored. The input is not modified.
positions : (N, 2) array, `~astropy.table.Table` or `~astropy.coordinates.SkyCoord`
    Initial positions: (x, y) pixel coordinates (0-based, as in numpy
    and photutils); a table with pixel columns (``x_centroid`` /
    ``y_centroid`` as made by `~lensdual.detection.find_point_sources`,
    or ``x`` / ``y``, ``x_init`` / ``y_init``, ``x_fit`` / ``y_fit``;
    its ``id`` column is kept); or sky positions (needs a WCS). A
    position off the image (or not finite) is not fitted: its row is NaN
    and flagged ``OUTSIDE_IMAGE``.
""",
    "label": r"""
label : str, optional
    How messages name the image, e.g. ``"arc L1, band F150W"``; the file
    in the image's ``meta['FILENAME']`` (or ``filename``, ``file``) is
    added when present. Default ``"image"``.
""",
    "settings": r"""
psf : `~astropy.units.Quantity`, float, 2-D array, `~photutils.psf.ImagePSF` or None, optional
    The PSF: a circular Gaussian of this FWHM (an angle, which needs a
    celestial WCS, a Quantity in ``u.pix``, or a number of pixels),
    integrated over the pixels; a 2-D PSF image (any normalisation: it is
    rescaled; centred on its central pixel; detector-sampled, or
    oversampled with ``oversampling``); or a photutils
    `~photutils.psf.ImagePSF` (used as it is, with its oversampling and
    normalisation). None (default): a Gaussian whose FWHM is fitted
    first to all sources (the inverse-variance weighted median of the
    per-source FWHM), then held fixed; it is recorded in
    ``meta['fwhm']``.
fit_shape : int or (int, int), optional
    Odd size (ny, nx) of the fitting box, >= 3. Default: 2 * ceil(2 *
    FWHM) + 1 pixels (at least 9) for ``"ridge"``, 2 * ceil(1.5 * FWHM)
    + 1 (at least 5) otherwise; the FWHM of an image PSF is the diameter
    of its area above half maximum.
background : str or `~photutils.background.LocalBackground`, optional
    How the light of the arc under each source is handled:

    * ``"ridge"`` (default): fit, with the PSF, an arc-aligned background
      :math:`f(u) + g(u)\,v + c\,v^2`, where :math:`u` runs across the
      arc and :math:`v` along it (directions from the image's structure
      tensor at the box centre), :math:`f` and :math:`g` are
      piecewise-linear on knots about 0.6 FWHM apart. The arc's cross
      profile is free, its variation along the arc is linear (plus a
      common curvature);
    * ``"residual"``: fit the *high-pass filtered* image,
      ``image - G * image`` with ``G`` a Gaussian of ``smooth_sigma``
      pixels (the residual image of `~lensdual.detection.PointSourceFilter`,
      without its clipping), with the *same filter applied to the PSF
      model* (which makes the flux exact: the filter also removes part of
      the source's own wings), plus a fitted constant;
    * ``"residual-plane"``: the same with a fitted tilted plane;
    * ``"plane"``, ``"quadratic"``, ``"constant"``: fit PSF plus a
      polynomial of order 1, 2 or 0 in the pixel offsets to the image;
    * ``"local"``: subtract the median in an annulus (photutils
      `~photutils.background.LocalBackground`, radii ``local_radii``),
      then fit the PSF alone; a `~photutils.background.LocalBackground`
      instance can be given instead of the string;
    * ``"none"``: fit the PSF alone (only for sources on an empty
      background).
smooth_sigma : float, optional
    Sigma, in pixels, of the Gaussian of the high-pass filter (the
    ``"residual"`` strategies); default 5, that of
    `~lensdual.detection.PointSourceFilter`. Must be > 0.
local_radii : (float, float), optional
    Inner and outer radii (pixels) of the annulus of ``"local"``;
    default (half the fit box + 1, that + 2 FWHM).
xy_bounds : float or None, optional
    Largest shift (pixels) of a fitted position from its initial one, in
    x and in y. None (default): half the fitting box (a source must stay
    in its box). Sources that end at the bound are flagged (``flags``
    bit 32).
group_radius : float, optional
    Sources closer than this (pixels) to another are fitted jointly: all
    their PSFs and one background over the union of their boxes (with
    astropy's `~astropy.modeling.fitting.TRFLSQFitter`, as photutils
    would). Default: 2 FWHM; 0 fits every source on its own.
neighbour_passes : int, optional
    Largest number of refinement passes in which every source that has
    neighbours (sources whose fitting boxes or PSF wings overlap) is
    refitted on the image minus the fitted PSFs of all the others; the
    passes stop when no flux or position changes by more than 0.05
    sigma. Default 10; 0 fits each source alone. Sources far from any
    other are fitted once.
maxiters : int, optional
    Largest number of function evaluations of the least-squares fitter
    per source.
warn : bool, optional
    Emit a `~lensdual.exceptions.LensdualWarning` when some fits are
    flagged (default True). photutils' own warnings are never passed
    on: they are summarised in that one warning.
oversampling : int or (int, int), optional
    Oversampling factor(s) (oy, ox) of a 2-D PSF image ``psf``: its
    pixels per detector pixel, e.g. 4 for the ``OVERSAMP`` image (HDU 0)
    of a WebbPSF/STPSF file (header keyword ``OVERSAMP``). The image is
    used as an effective PSF, as photutils' ``ImagePSF(data,
    oversampling=...)``. Default None: not oversampled. Only for a PSF
    image (a ValueError otherwise, or when it contradicts an ImagePSF's
    own).
check_psf : bool, optional
    With a PSF image (default True): fit a Gaussian FWHM to the (at most
    6) brightest sources before the photometry, and refuse (ValueError) a
    PSF more than 1.8 times wider than them (an oversampled PSF passed
    without ``oversampling``), or 1.8 times narrower when an
    ``oversampling`` was given; warn when it is narrower without one.
    With a Gaussian ``psf`` of given FWHM, warn when it is 1.8 times
    narrower than the sources (``source_model="point"`` only).
source_model : {"point", "resolved"}, optional
    ``"point"`` (default): every source is the PSF. ``"resolved"``: after
    the PSF fit, every source is refitted alone as the PSF convolved with an
    elliptical Gaussian of free covariance (see :ref:`photometry-resolved`),
    on the image minus the other sources' models, with the same background
    columns; its flux is the model's total flux, so a slightly resolved
    source (a star cluster stretched along an arc) keeps all its flux. The
    fitted size is reported (``size``, ``size_minor``, ``size_angle``,
    ``size_snr``, ``flux_outside``) and the PSF fluxes are kept in
    ``flux_point``; a source whose model puts more than 10 % of its flux
    outside the fitting box is flagged ``TOO_RESOLVED`` (unusable).
""",
    "returns": r"""
table : `~astropy.table.QTable`
    One row per position, in input order:

    * ``id``: from the positions table, or 1, 2, ...;
    * ``x_init``, ``y_init``: initial pixel position;
    * ``x_fit``, ``y_fit``, ``x_err``, ``y_err``: fitted position and its
      1-sigma errors (pixels, 0-based);
    * ``flux``, ``flux_err``: total PSF flux and its 1-sigma error, in the
      image unit (a Quantity when the image has one);
    * ``bkg``: the fitted background at the source position (for the
      ``"residual"`` strategies: in the filtered image; for ``"local"``:
      the annulus estimate), image unit;
    * ``sky``: `~astropy.coordinates.SkyCoord` of the fitted position
      (only with a celestial WCS);
    * ``group_size``: 1, or the number of sources fitted jointly with it;
    * ``qfit``, ``cfit``, ``reduced_chi2``, ``n_pixels_fit``, ``flags``:
      photutils' fit-quality columns and flags (see
      `~photutils.psf.PSFPhotometry`; ``flags == 0`` is a clean fit; the
      same definitions for jointly fitted groups, whose ``reduced_chi2``
      is that of the whole group), plus lensdual's own bits: see
      :class:`PhotometryFlag`;
    * ``flag_note``: the flags in words (:func:`describe_flags`), "" for
      a clean fit.

    The errors come from the fit covariance, marginalised over the
    background parameters: with pixel errors (an uncertainty) it is the
    inverse Fisher matrix of the weighted fit; without, it is scaled by
    the reduced chi-square. ``meta`` records the PSF, FWHM (pixels),
    fit shape, background strategy and smoothing, the PSF image's
    ``oversampling`` and ``input`` (how messages name the image).

    With ``source_model="resolved"`` the fluxes, positions and their errors
    are those of the resolved fit, and the table has also:

    * ``flux_point``, ``flux_point_err``: the PSF fit's flux and error;
    * ``size``, ``size_minor``: the standard deviations (pixels) of the
      fitted Gaussian along its major and minor axes, before the PSF; a
      negative value is the signed square root of a negative fitted
      variance (a point source's size scatters about 0);
    * ``size_angle``: the major axis' angle (degrees from +x towards +y);
    * ``size_snr``: the major-axis variance over its error (> 3: resolved);
    * ``flux_outside``: the fraction of the fitted model's flux outside the
      fitting box (above 0.1 the source is flagged ``TOO_RESOLVED``).
""",
}


def _fill_doc(obj):
    """Replace every ``@name@`` line of ``obj``'s docstring by the part ``name``
    of ``_DOC_PARTS``, indented as the line was; returns ``obj``."""
    lines = []
    for line in obj.__doc__.split("\n"):
        name = line.strip()[1:-1]
        if line.strip() == f"@{name}@" and name in _DOC_PARTS:
            part = _DOC_PARTS[name].strip("\n")
            lines.append(textwrap.indent(part, line[:line.index("@")]))
        else:
            lines.append(line)
    obj.__doc__ = "\n".join(lines)
    return obj


@_fill_doc
class ArcPSFPhotometry:
    r"""PSF photometry of point sources on a bright arc, set up once and called on images.

    Each source is fitted with photutils' `~photutils.psf.PSFPhotometry`
    (flux and position free) in a ``fit_shape`` box about its initial
    position, together with a local background model chosen by
    ``background``; see :ref:`photometry` for the strategies and how they
    compare on a bright, curved, steep arc. The settings are checked here,
    once; calling the object on an image and positions measures them, as
    :func:`psf_photometry` does with the same settings.

    Parameters
    ----------
    @settings@

    Raises
    ------
    TypeError
        ``psf``, ``background`` or ``local_radii`` of the wrong type.
    ValueError
        A non-positive FWHM, a bad ``fit_shape``, an unknown background
        strategy, a bad ``smooth_sigma``, ``xy_bounds``, ``group_radius``,
        ``neighbour_passes``, ``maxiters``, ``local_radii`` or
        ``oversampling``.

    See Also
    --------
    psf_photometry : The same in one call.
    measure_pairs : The photometry of every band of two arcs, into a pairs table.

    Examples
    --------
    Two point sources of 1000 and 600 counts (Gaussian PSF of FWHM 2.5
    pixels) on a tilted background, measured with a fitted plane:

    >>> import numpy as np
    >>> from scipy.special import erf
    >>> from lensdual.photometry import ArcPSFPhotometry
    >>> def gaussian_prf(dx, dy, sigma=2.5 / 2.3548):
    ...     k = 1 / (np.sqrt(2) * sigma)
    ...     side = lambda t: 0.5 * (erf((t + 0.5) * k) - erf((t - 0.5) * k))
    ...     return side(dx) * side(dy)
    >>> yy, xx = np.mgrid[:40, :60]
    >>> image = 5.0 + 0.1 * xx + 0.05 * yy
    >>> for (x, y), flux in zip([(20.3, 18.6), (41.7, 22.2)], [1000.0, 600.0]):
    ...     image += flux * gaussian_prf(xx - x, yy - y)
    >>> phot = ArcPSFPhotometry(2.5, background="plane")
    >>> table = phot(image, [(20.0, 19.0), (42.0, 22.0)])
    >>> np.round(table["flux"], 3).tolist()
    [1000.0, 600.0]
    >>> np.round(table["x_fit"], 3).tolist()
    [20.3, 41.7]
    """

    def __init__(
        self,
        psf=None,
        *,
        fit_shape=None,
        background=_DEFAULT_BACKGROUND,
        smooth_sigma=5.0,
        local_radii=None,
        xy_bounds=None,
        group_radius=None,
        neighbour_passes=10,
        maxiters=100,
        warn=True,
        oversampling=None,
        check_psf=True,
        source_model="point",
    ):
        from photutils.background import LocalBackground

        if source_model not in SOURCE_MODELS:
            raise ValueError(f"source_model must be one of {list(SOURCE_MODELS)}, got "
                             f"{source_model!r}")
        self._source_model = source_model

        self._oversampling = _as_oversampling(oversampling)
        self._psf_kind, self._psf = _psf_spec(psf, oversampling=self._oversampling)
        local_est = None
        if isinstance(background, LocalBackground):
            local_est = background
            strategy = "local"
        elif isinstance(background, str):
            if background not in _STRATEGY:
                raise ValueError(
                    f"background must be one of {list(BACKGROUND_STRATEGIES)} or a photutils "
                    f"LocalBackground, got {background!r}"
                )
            strategy = background
        else:
            raise TypeError(
                f"background must be a string or a photutils LocalBackground, got "
                f"{type(background).__name__}"
            )
        self._strategy = strategy
        image_kind, self._basis_kind = _STRATEGY[strategy]
        self._smooth_sigma = as_real(smooth_sigma, "smooth_sigma", minimum=0, inclusive=False)
        self._neighbour_passes = as_int(neighbour_passes, "neighbour_passes", minimum=0)
        self._maxiters = as_int(maxiters, "maxiters", minimum=1)
        self._xy_bounds = None
        if xy_bounds is not None:
            self._xy_bounds = as_real(xy_bounds, "xy_bounds", minimum=0, inclusive=False)
        self._group_radius = None
        if group_radius is not None:
            self._group_radius = as_real(group_radius, "group_radius", minimum=0)
        self._highpass = self._smooth_sigma if image_kind == "highpass" else None
        self._fit_shape = None if fit_shape is None else _fit_shape(fit_shape, None, strategy)
        if strategy == "local" and local_est is None and local_radii is not None:
            local_est = _local_background(local_radii)
        self._local_est = local_est
        self._warn = warn
        self._check_psf = check_psf
        self._given = {
            "psf": psf,
            "fit_shape": fit_shape,
            "background": background,
            "smooth_sigma": smooth_sigma,
            "local_radii": local_radii,
            "xy_bounds": xy_bounds,
            "group_radius": group_radius,
            "neighbour_passes": neighbour_passes,
            "maxiters": maxiters,
            "warn": warn,
            "oversampling": oversampling,
            "check_psf": check_psf,
            "source_model": source_model,
        }

    def __repr__(self):
        settings = ", ".join(f"{k}={v!r:.60}" for k, v in self._given.items())
        return f"{type(self).__name__}({settings})"

    @_fill_doc
    def __call__(self, image, positions, *, label=None):
        """Measure the point sources of one image.

        Parameters
        ----------
        @image_positions@
        @label@

        Returns
        -------
        @returns@

        Raises
        ------
        TypeError
            ``image`` or ``positions`` of the wrong type.
        ValueError
            An angular FWHM or sky positions without a WCS, a PSF image whose
            width does not match the sources (see ``check_psf``), an image
            without any valid pixel (all NaN, an error map zero or NaN
            everywhere, all masked: the message names the image, its file and
            what to check), a cube of several planes. (Bad settings raise when
            the object is made.)

        Warns
        -----
        LensdualWarning
            Some fits are flagged (did not converge, no covariance, non-positive
            flux, positions off the image, ...); an image of shape (1, ny, nx)
            (a cube with NAXIS3 = 1) used as its 2-D plane.
        """
        return self._measure(image, positions, label)

    # The steps of a call. _measure is called by __call__ and psf_photometry alike,
    # so that the warnings' stacklevel, counted from _measure, names the caller.

    def _measure(self, image, positions, label):
        """The photometry of ``image`` (see `__call__`)."""
        parts = _split_parts(image, "image", label, stacklevel=5)
        where, unit, wcs = parts[0], parts[3], parts[4]
        full_shape = parts[1].shape
        kind, spec = _psf_in_pixels(self._psf_kind, self._psf, wcs, full_shape)
        x_all, y_all, ids, off = _positions(positions, wcs, full_shape)
        reader = _ImageReader(image, label, parts, x_all[~off], y_all[~off], self._highpass)
        fwhm = _image_fwhm(spec) if kind == "image" else (2.5 if spec is None else spec)
        shape = self._fit_shape or _fit_shape(None, fwhm, self._strategy)
        local_est = self._local_estimator(shape, fwhm)
        margin = _cutout_margin(self._basis_kind, shape, fwhm, self._highpass, local_est)
        fitdata, invalid, error, x, y, offset, box = reader.read(margin)
        local_bkg = self._local_bkg(local_est, fitdata, invalid, x, y)
        scene = _Scene(fitdata, invalid, error, x, y, local_bkg)
        if kind == "gaussian" and spec is None:  # the FWHM is fitted first
            if x.size == 0:
                fwhm = np.nan
            else:
                fwhm, shape = self._fitted_fwhm(scene, shape, fwhm)
                wider = _cutout_margin(self._basis_kind, shape, fwhm, self._highpass, local_est)
                if box is not None and wider > margin:  # a wider PSF than assumed
                    fitdata, invalid, error, x, y, offset, box = reader.read(wider)
                    scene = _Scene(fitdata, invalid, error, x, y, local_bkg)
        res, caught, failed, profile = self._fit(scene, kind, spec, shape, fwhm, where)
        if offset != (0, 0):  # back to the pixel coordinates of the whole image
            res["x_fit"] = res["x_fit"] + offset[0]
            res["y_fit"] = res["y_fit"] + offset[1]
        out = _result_table(_all_rows(res, off), ids, x_all, y_all, unit, wcs)
        if profile is not None:
            out.meta["psf"] = profile.describe()
        elif kind == "gaussian":
            out.meta["psf"] = f"Gaussian FWHM {fwhm:.4g} px"
        else:
            out.meta["psf"] = f"image PSF {spec.data.shape}"
        out.meta["fwhm"] = fwhm
        out.meta["fwhm_estimated"] = kind == "gaussian" and spec is None
        out.meta["fit_shape"] = shape
        out.meta["background"] = self._strategy
        out.meta["smooth_sigma"] = self._highpass
        out.meta["neighbour_passes"] = self._neighbour_passes
        out.meta["group_radius"] = 2.0 * fwhm if self._group_radius is None else self._group_radius
        out.meta["weighted"] = error is not None
        out.meta["oversampling"] = (
            None if kind != "image" else [int(v) for v in np.broadcast_to(spec.oversampling, 2)]
        )
        out.meta["input"] = where
        out.meta["source_model"] = self._source_model
        if self._warn:
            _warn_flagged(out, caught, failed, (x_all, y_all, ids, off), full_shape, where)
        return out

    def _local_estimator(self, shape, fwhm):
        """The annulus estimator of the ``"local"`` strategy (None for the others)."""
        if self._strategy != "local" or self._local_est is not None:
            return self._local_est
        inner = max(shape) // 2 + 1.0
        return _local_background((inner, inner + 2.0 * fwhm))

    @staticmethod
    def _local_bkg(local_est, fitdata, invalid, x, y):
        """The annulus background under each source (zeros without an estimator)."""
        if local_est is None:
            return np.zeros(x.size)
        if x.size == 0:
            return np.zeros(0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            local_bkg = np.atleast_1d(
                np.asarray(local_est(fitdata, x, y, mask=invalid), dtype=np.float64)
            )
        return np.where(np.isfinite(local_bkg), local_bkg, 0.0)

    def _fitted_fwhm(self, scene, shape, fwhm):
        """The Gaussian FWHM fitted to the sources (starting from ``fwhm``) and the
        fitting box for it."""
        basis = _make_basis(
            self._basis_kind, scene.data, scene.invalid, shape, fwhm, scene.x, scene.y
        )
        fwhm = _estimate_fwhm(scene, self._highpass, basis, shape, self._xy_bounds, self._maxiters)
        if self._fit_shape is None:
            shape = _fit_shape(None, fwhm, self._strategy)
        return fwhm, shape

    def _fit(self, scene, kind, spec, shape, fwhm, where):
        """Fit the sources of ``scene``; returns (results, caught, failed, profile)."""
        if scene.x.size == 0:  # nothing on the image: every row NaN, flagged OUTSIDE_IMAGE
            res = {col: np.full(0, np.nan) for col in _RESULT_COLUMNS + ("bkg_at",)}
            res["group_size"] = np.zeros(0, np.int64)
            return res, [], [], None
        basis = _make_basis(
            self._basis_kind, scene.data, scene.invalid, shape, fwhm, scene.x, scene.y
        )
        if kind == "gaussian":
            profile = _GaussianProfile(fwhm, self._highpass)
        else:
            profile = _ImageProfile(spec, self._highpass)
        fitter = _SourceFitter(
            scene, profile, basis, shape, xy_bound=self._xy_bounds, maxiters=self._maxiters
        )
        if kind == "image" and self._check_psf:
            # before the fit: a wrong PSF (e.g. oversampled without its factor) makes
            # wide groups whose joint fits are slow, and its fluxes are wrong anyway
            self._check_image_psf(fitter, where)
        elif (kind == "gaussian" and spec is not None and self._check_psf
              and self._source_model == "point"):
            # a given FWHM only: a fitted one is the sources' own width
            self._check_resolved(fitter, where)
        radius = 2.0 * fwhm if self._group_radius is None else self._group_radius
        res, caught, failed = fitter.fit(self._neighbour_passes, radius)
        if self._source_model == "resolved":
            failed = failed + refit_resolved(fitter, res)
        return res, caught, failed, profile

    def _sources_fwhm(self, fitter):
        """The Gaussian FWHM (pixels) fitted to the (at most 6) brightest sources and how
        many; None when no fit is usable."""
        lin = fitter.linear_init()[:, 0]
        amp = np.where(np.isfinite(lin) & (lin > 0), lin, 0.0)
        order = np.argsort(-amp)
        pick = order[amp[order] > 0][:_PSF_CHECK_SOURCES]
        if pick.size == 0:
            return None
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                fwhm_data = _estimate_fwhm(
                    fitter.scene.subset(pick),
                    self._highpass,
                    fitter.basis,
                    fitter.fit_shape,
                    self._xy_bounds,
                    self._maxiters,
                    max_rel_err=0.2,
                )
        except ValueError:  # no usable Gaussian fit: nothing to compare with
            return None
        return fwhm_data, pick.size

    def _check_resolved(self, fitter, where):
        """Warn when the sources are much wider than a Gaussian PSF of given FWHM."""
        got = self._sources_fwhm(fitter)
        if got is None:
            return
        fwhm_data, n = got
        ratio = fitter.profile.fwhm / fwhm_data
        if ratio < 1.0 / _PSF_WIDTH_TOLERANCE:
            # stacklevel: _check_resolved, _fit, _measure, __call__ or psf_photometry, caller
            warnings.warn(
                f"{where}: the PSF (Gaussian FWHM {fitter.profile.fwhm:.2f} px) is "
                f"{1.0 / ratio:.1f} times narrower than the point sources (Gaussian FWHM "
                f"{fwhm_data:.2f} px fitted to the {n} brightest): {_RESOLVED_ADVICE}",
                LensdualWarning,
                stacklevel=5,
            )

    def _check_image_psf(self, fitter, where):
        """Compare the width of an image PSF with the sources' own (a Gaussian FWHM fit).

        The Gaussian FWHM is fitted to the (at most 6) brightest sources (by
        their linear PSF amplitude), each alone in the PSF's fitting box; only
        fits whose FWHM is known to 20 % count. A PSF more than 1.8 times wider
        than the sources cannot be right (a point source is never narrower than
        the PSF) and is a ValueError: the usual cause is an oversampled PSF image
        passed without its ``oversampling``. A PSF 1.8 times narrower is a
        ValueError too when an ``oversampling`` > 1 was given (it may not apply),
        else a warning (the sources may be resolved). Without any usable fit
        nothing is checked.
        """
        got = self._sources_fwhm(fitter)
        if got is None:
            return
        fwhm_data, n_fitted = got
        fwhm_psf = fitter.profile.fwhm
        ratio = fwhm_psf / fwhm_data
        oversampling = self._oversampling
        given = "no oversampling" if oversampling is None else f"oversampling={list(oversampling)}"
        facts = (
            f"{where}: the PSF image (FWHM {fwhm_psf:.2f} px with {given}) is {{}} than the "
            f"point sources (Gaussian FWHM {fwhm_data:.2f} px fitted to the {n_fitted} "
            "brightest)"
        )
        if ratio > _PSF_WIDTH_TOLERANCE:
            guess = max(2, int(np.round(ratio)))
            raise ValueError(
                facts.format(f"{ratio:.1f} times wider")
                + f", which would give wrong fluxes. Is the PSF oversampled (a WebbPSF/STPSF "
                f"file's HDU 0, OVERSAMP)? Pass oversampling= its factor (header keyword "
                f"OVERSAMP; about {guess} here) or use the detector-sampled PSF (HDU 1, "
                "DET_SAMP); check_psf=False skips this check"
            )
        if ratio < 1.0 / _PSF_WIDTH_TOLERANCE:
            text = facts.format(f"{1.0 / ratio:.1f} times narrower")
            if oversampling is not None and oversampling != (1, 1):
                raise ValueError(
                    text + f": is the PSF image really oversampled by {list(oversampling)}? "
                    "Check its OVERSAMP header keyword, or leave oversampling out for a "
                    "detector-sampled PSF; check_psf=False skips this check"
                )
            # stacklevel: _check_image_psf, _fit, _measure, __call__ or psf_photometry, caller
            if self._source_model == "point":
                warnings.warn(
                    text + ": resolved sources, or a PSF image of another pixel scale. "
                    + _RESOLVED_ADVICE,
                    LensdualWarning,
                    stacklevel=5,
                )


def _local_background(local_radii):
    """A photutils LocalBackground of annulus radii ``local_radii`` (pixels)."""
    from photutils.background import LocalBackground

    try:
        r_in, r_out = (float(v) for v in local_radii)
    except (TypeError, ValueError):
        raise TypeError(
            f"local_radii must be a pair of numbers (pixels), got {local_radii!r}"
        ) from None
    if not (0 <= r_in < r_out):
        raise ValueError(f"local_radii must satisfy 0 <= inner < outer, got {local_radii}")
    return LocalBackground(r_in, r_out)


def _all_rows(res, off):
    """The fit results (of the positions on the image) back to one row per position."""
    inside = ~off
    n_all = off.size
    full = {}
    extra = tuple(c for c in RESOLVED_COLUMNS if c in res)
    for col in _RESULT_COLUMNS + ("bkg_at",) + extra:
        full[col] = np.full(n_all, np.nan)
        full[col][inside] = res[col]
    full["flags"] = np.full(n_all, int(PhotometryFlag.OUTSIDE_IMAGE), np.int64)
    full["flags"][inside] = np.asarray(res["flags"], dtype=np.int64)
    full["n_pixels_fit"] = np.zeros(n_all, np.int64)
    full["n_pixels_fit"][inside] = np.nan_to_num(res["n_pixels_fit"]).astype(np.int64)
    full["group_size"] = np.zeros(n_all, np.int64)
    full["group_size"][inside] = res["group_size"]
    flux_ok = np.isfinite(full["flux_fit"])
    bad_err = inside & flux_ok & ~(np.isfinite(full["flux_err"]) & (full["flux_err"] > 0))
    full["flags"][bad_err] |= int(PhotometryFlag.BAD_ERROR)
    return full


def _result_table(res, ids, x_all, y_all, unit, wcs):
    """The output table of the photometry, without its ``meta``."""
    out = QTable()
    out["id"] = ids
    out["x_init"] = x_all
    out["y_init"] = y_all
    for name in ("x_fit", "y_fit", "x_err", "y_err"):
        out[name] = res[name]
    flux, flux_err, bkg = res["flux_fit"], res["flux_err"], res["bkg_at"]
    if unit is not None:
        flux, flux_err, bkg = flux * unit, flux_err * unit, bkg * unit
    out["flux"] = flux
    out["flux_err"] = flux_err
    out["bkg"] = bkg
    if wcs is not None:
        try:
            sky = wcs.pixel_to_world(res["x_fit"], res["y_fit"])
        except Exception:  # noqa: BLE001 - a WCS without celestial axes: no sky column
            sky = None
        if isinstance(sky, SkyCoord):
            out["sky"] = sky
    for name in ("group_size", "qfit", "cfit", "reduced_chi2", "n_pixels_fit", "flags"):
        out[name] = res[name]
    if "flux_point" in res:
        point, point_err = res["flux_point"], res["flux_point_err"]
        if unit is not None:
            point, point_err = point * unit, point_err * unit
        out["flux_point"] = point
        out["flux_point_err"] = point_err
        for name in RESOLVED_COLUMNS[2:]:
            out[name] = res[name]
    out["flag_note"] = [describe_flags(f) for f in res["flags"]]
    return out


def _warn_flagged(out, caught, failed, positions, shape, where):
    """One LensdualWarning for the flagged fits, positions off the image, fits that
    raised and photutils' warnings, if any."""
    x_all, y_all, ids, off = positions
    bad = (out["flags"] & _BAD_FLAGS) != 0
    if not (bad.any() or caught or failed or off.any()):
        return
    msgs = sorted({str(w.message) for w in caught})
    text = f"psf_photometry ({where}): {int(bad.sum())} of {len(out)} fits flagged"
    if bad.any():
        text += f" (ids {out['id'][bad].tolist()[:20]}; see the flags columns)"
    if off.any():
        text += "; " + _outside_text(x_all, y_all, off, ids, shape)
    if failed:
        text += "; fits that raised: " + " | ".join(failed[:5])
    if msgs:
        text += "; photutils: " + " | ".join(msgs)
    # stacklevel: _warn_flagged, _measure, __call__ or psf_photometry, caller
    warnings.warn(text, LensdualWarning, stacklevel=4)


@_fill_doc
def psf_photometry(
    image,
    positions,
    *,
    psf=None,
    fit_shape=None,
    background=_DEFAULT_BACKGROUND,
    smooth_sigma=5.0,
    local_radii=None,
    xy_bounds=None,
    group_radius=None,
    neighbour_passes=10,
    maxiters=100,
    warn=True,
    oversampling=None,
    check_psf=True,
    label=None,
    source_model="point",
):
    r"""PSF photometry of point sources on a bright arc, from given positions.

    Each source is fitted with photutils' `~photutils.psf.PSFPhotometry`
    (flux and position free) in a ``fit_shape`` box about its initial
    position, together with a local background model chosen by
    ``background``; see :ref:`photometry` for the strategies and how they
    compare on a bright, curved, steep arc.

    Parameters
    ----------
    @image_positions@
    @settings@
    @label@

    Returns
    -------
    @returns@

    Raises
    ------
    TypeError
        ``image``, ``positions``, ``psf`` or ``background`` of the wrong
        type.
    ValueError
        Non-positive FWHM, a bad ``fit_shape``, an unknown background
        strategy, an angular FWHM or sky positions without a WCS, a bad
        ``oversampling``, a PSF image whose width does not match the sources
        (see ``check_psf``), an image without any valid pixel (all NaN, an
        error map zero or NaN everywhere, all masked: the message names the
        image, its file and what to check), a cube of several planes.

    Warns
    -----
    LensdualWarning
        Some fits are flagged (did not converge, no covariance, non-positive
        flux, positions off the image, ...); an image of shape (1, ny, nx)
        (a cube with NAXIS3 = 1) used as its 2-D plane.

    See Also
    --------
    ArcPSFPhotometry : The same, set up once and called on images;
        ``psf_photometry(image, positions, label=label, **settings)`` is
        ``ArcPSFPhotometry(**settings)(image, positions, label=label)``.

    Examples
    --------
    A point source of 500 counts at (15.4, 14.8), a Gaussian PSF of FWHM 2.5
    pixels integrated over the pixels, on a flat background of 10, fitted
    from the initial position (15, 15):

    >>> import numpy as np
    >>> from scipy.special import erf
    >>> from lensdual.photometry import psf_photometry
    >>> k = np.sqrt(2) * 2.5 / 2.3548  # sqrt(2) sigma
    >>> px = np.diff(erf((np.arange(32) - 0.5 - 15.4) / k)) / 2
    >>> py = np.diff(erf((np.arange(32) - 0.5 - 14.8) / k)) / 2
    >>> image = 10.0 + 500.0 * np.outer(py, px)
    >>> table = psf_photometry(image, [(15.0, 15.0)], psf=2.5, background="constant")
    >>> round(float(table["flux"][0]), 1)
    500.0
    >>> round(float(table["x_fit"][0]), 2), round(float(table["y_fit"][0]), 2)
    (15.4, 14.8)
    >>> int(table["flags"][0])
    0

    Without ``psf`` the FWHM is fitted first:

    >>> table = psf_photometry(image, [(15.0, 15.0)])
    >>> round(float(table.meta["fwhm"]), 2)
    2.5
    """
    phot = ArcPSFPhotometry(
        psf,
        fit_shape=fit_shape,
        background=background,
        smooth_sigma=smooth_sigma,
        local_radii=local_radii,
        xy_bounds=xy_bounds,
        group_radius=group_radius,
        neighbour_passes=neighbour_passes,
        maxiters=maxiters,
        warn=warn,
        oversampling=oversampling,
        check_psf=check_psf,
        source_model=source_model,
    )
    return phot._measure(image, positions, label)

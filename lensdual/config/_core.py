r"""Configuration files of ``lensdual run``: schema, validation and loading.

A run is described by a TOML file. :func:`load_config` reads it, checks every
table, key, value and referenced file (FITS headers and HDUs, ECSV columns)
and returns a :class:`RunConfig`; all the problems it finds are reported
together in one :class:`ConfigError`. :func:`load_images` then reads the
images as `~astropy.nddata.CCDData` (with WCS, uncertainty, mask and PSF) and
:func:`band_psfs` gives the PSF of every band in the form
:func:`~lensdual.photometry.psf_photometry` accepts. :func:`format_config` and
:func:`write_config` write a nested dictionary as TOML text.

.. rubric:: The schema

Every table and key below is shown; tables and keys marked optional may be
left out. Relative paths are relative to the directory of the configuration
file. Angles are strings of a number and an angular unit (``"0.066 arcsec"``,
``"10 mas"``, ``"1.2e-5 deg"``). ::

    [output]
    outdir = "lensdual-output"       # optional; default "lensdual-output"

    [analysis]                       # optional, as is every key in it
    estimator = "adaptive"           # "adaptive" (default), "2v", "quad" or "quad2"
    sigma_pos = "auto"               # "auto" (errors of the PSF fits) or an angle > 0
    n_bootstrap = 1000               # integer >= 10
    snr_threshold = 3.0              # real > 0
    seed = 0                         # integer >= 0
    null_realisations = 0            # 0 (off) or >= 100: null calibration (estimator "adaptive")

    [bands.F150W]                    # one table per band, at least one band
    psf = "psf_F150W.fits"           # a PSF image (FITS, odd shape, same pixel scale
    psf_hdu = 0                      #   as the images); psf_hdu: index or EXTNAME
    [bands.F200W]
    psf_oversampling = 4             # optional, with psf: its oversampling (default:
                                     #   the file's OVERSAMP keyword, as WebbPSF writes)
    psf_fwhm = "0.066 arcsec"        # or the FWHM of a Gaussian PSF (not both);
                                     # neither: the FWHM is fitted to the sources

    [arcs.L1.F150W]                  # arcs L1 and L2, each with every band of [bands]
    image = "L1_F150W.fits"          # required; needs a celestial WCS
    hdu = "SCI"                      # optional index or EXTNAME
    error = "L1_F150W_err.fits"      # optional 1-sigma error map (same shape), or
    error_hdu = 1                    # weight = "..." / weight_hdu: an inverse-variance
                                     # map (not both); an error_hdu (weight_hdu)
                                     # without error (weight) reads the image's file
    unit = "nJy"                     # optional; else BUNIT; else dimensionless
                                     # A pipeline product (JWST *_i2d, HST *_drz/_drc)
                                     # needs image only: its SCI, ERR (else WHT)
                                     # extensions are found; MJy/sr with PIXAR_SR
                                     # becomes nJy per pixel; an exposure-time WHT
                                     # is scaled to the image's sky noise (warning)
    [arcs.L1.F200W]
    image = "L1_F200W.fits"
    [arcs.L1.cutout]                 # optional, per arc ("cutout" is no band name)
    center = "110.8 -73.45"          # ICRS; plain numbers are degrees; also
                                     # "07h23m12s -73d27m00s" or "07:23:12 -73:27:00"
    size = "6 arcsec"                # or ["6 arcsec", "4 arcsec"] (ny, nx)
    [arcs.L2.F150W]
    image = "L2_F150W.fits"
    [arcs.L2.F200W]
    image = "L2_F200W.fits"

    [catalogs]                       # optional: skip the detection, use these
    L1 = "L1_sources.ecsv"           # ECSV: integer 'id' column and a SkyCoord column
    L2 = "L2_sources.ecsv"           # 'sky' or 'ra', 'dec' columns (deg); both or neither

    [pairing]
    method = "auto"                  # "auto" (default) or "manual"
    file = "pairs.ecsv"              # manual only (and then required): ECSV with
                                     # integer columns id1, id2 (catalogue ids)

    [parametric]                     # optional
    lenstool = "best.par"            # optional Lenstool parameter file
    fit = false                      # fit a lenstronomy model to the pairs
    model = ["NFW_ELLIPSE_CSE", "SHEAR"]   # profiles of the fit (this is the default)
    z_lens = 0.39                    # required with fit = true or lenstool
    z_source = 2.2                   # required with fit = true or lenstool; > z_lens
    sigma_pos = "0.01 arcsec"        # positional error of the fit (default 0.01 arcsec)
    centre = "110.827 -73.4545"      # optional origin of the fit's frame (e.g. the BCG)
    fix_centre = false               # hold the first profile's centre there (needs centre)

A catalogue-only run (no images) replaces ``[bands]``, ``[arcs]``,
``[catalogs]``, ``[pairing]`` and ``[parametric]`` by one ``[knots]`` table: the
knots of a multiply-imaged galaxy in a published multiple-image catalogue,
paired across its macro-images (:func:`lensdual.pairing.pairs_from_knots`) and
compared with lens models (:func:`lensdual.parametric.compare_size_with_models`)::

    [knots]
    catalogue = "knots.mul"          # Lenstool catalogue, or ECSV with 'id' and 'sky'
                                     # (or 'ra', 'dec' in deg)
    macro_images = ["1.1", "1.2", "1.3"]   # at least 2 names
    centres = "catalogue"            # optional: "catalogue" (commented lines of the
                                     # catalogue, the default) or a table of "RA Dec"
    systems = [1000, 2000]           # optional: knot systems with integer ids in
                                     # [lo, hi), or a list of system names; default all
    assign = "model"                 # optional: "centre", "mapping" or "model" (default:
                                     # "mapping" with a mapping, "model" with models)
    mapping = "mapping.ecsv"         # ECSV with columns id, macro (assign = "mapping")
    models = ["best.par"]            # optional Lenstool models; the first assigns
    z_source = 1.4888                # optional (default: the catalogue's redshift)
    sigma_pos = "auto"               # "auto" (measured per pair of macro-images from the
                                     # constellation's residuals) or an angle

The output directory given to :func:`load_config` (``outdir=``, e.g. from
the command line) replaces ``[output] outdir``; it is resolved against the
current directory, the configuration value against the configuration file's
directory.
"""

import difflib
import math
import os
import re
import tempfile
import tomllib
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.io import fits
from astropy.nddata import CCDData, Cutout2D, StdDevUncertainty
from astropy.nddata.utils import NoOverlapError
from astropy.table import Table
from astropy.wcs import WCS, FITSFixedWarning

from ..estimators import METHODS

__all__ = [
    "ConfigError",
    "ImageSpec",
    "BandSpec",
    "ArcSpec",
    "ParametricSpec",
    "KnotSpec",
    "RunConfig",
    "load_config",
    "load_images",
    "band_psfs",
    "band_oversampling",
    "format_config",
    "write_config",
]

_ARCS = ("L1", "L2")
_CUTOUT = "cutout"
_DEFAULT_OUTDIR = "lensdual-output"
_DEFAULT_MODEL = ("NFW_ELLIPSE_CSE", "SHEAR")
_PAIRING_METHODS = ("auto", "manual")
_MIN_PAIRS = 3
_MIN_PSF_SIZE = 5
#: Bands of an arc share one pixel grid when their WCSs agree to this many pixels.
_GRID_TOLERANCE = 0.01
#: An error map disagreeing with the image's own sky noise by more than this
#: factor (either way) draws a warning.
_NOISE_FACTOR = 3.0

_KEYS = {
    "output": ("outdir",),
    "analysis": ("estimator", "sigma_pos", "n_bootstrap", "snr_threshold", "seed",
                 "null_realisations"),
    "bands": (),
    "arcs": (),
    "catalogs": _ARCS,
    "pairing": ("method", "file"),
    "parametric": ("lenstool", "fit", "model", "z_lens", "z_source", "sigma_pos", "centre",
                   "fix_centre"),
    "knots": ("catalogue", "macro_images", "centres", "systems", "assign", "mapping", "models",
              "z_source", "sigma_pos"),
}
#: Tables a catalogue-only ([knots]) run does without.
_IMAGE_TABLES = ("bands", "arcs", "catalogs", "pairing", "parametric")
_ASSIGN = ("centre", "mapping", "model")
_BAND_KEYS = ("psf", "psf_hdu", "psf_fwhm", "psf_oversampling")
_IMAGE_KEYS = ("image", "hdu", "error", "error_hdu", "weight", "weight_hdu", "unit")
_CUTOUT_KEYS = ("center", "size")

_ABSENT = object()  # a key that is not in its table
_BAD = object()  # a value that failed its checks (the problem is recorded)


def _valid(*values):
    """True if none of ``values`` is ``_BAD`` (by identity: values may be Quantities)."""
    return all(v is not _BAD for v in values)


# ---------------------------------------------------------------------------
# the error and the specification classes
# ---------------------------------------------------------------------------


class ConfigError(ValueError):
    """A configuration file, or a file it refers to, has problems.

    Parameters
    ----------
    problems : list of str or str
        One message per problem.
    path : path-like, optional
        The configuration file.

    Attributes
    ----------
    problems : list of str
        One message per problem, each naming the table and key concerned.
    path : `~pathlib.Path` or None
        The configuration file.

    Notes
    -----
    ``str(err)`` is a single message::

        <path>: 2 problems in the configuration:
          - [analysis] n_bootstrap: must be >= 10, got 5
          - [arcs.L2]: missing (arcs L1 and L2 are both required)
    """

    def __init__(self, problems, path=None):
        if isinstance(problems, str):
            problems = [problems]
        self.problems = list(problems)
        self.path = None if path is None else Path(path)
        super().__init__(self._message())

    def _message(self):
        n = len(self.problems)
        head = f"{n} problem{'' if n == 1 else 's'} in the configuration:"
        if self.path is not None:
            head = f"{self.path}: {head}"
        return "\n".join([head] + [f"  - {p}" for p in self.problems])

    def __str__(self):
        return self._message()

    def __reduce__(self):
        return type(self), (self.problems, self.path)


@dataclass(frozen=True)
class ImageSpec:
    """One image of an arc in one band, as given in ``[arcs.<arc>.<band>]``.

    Attributes
    ----------
    image : `~pathlib.Path`
        The FITS file of the image (absolute path).
    hdu : int, str or None
        The HDU of the image (index or EXTNAME); None: the first HDU with
        2-D image data.
    error : `~pathlib.Path` or None
        The FITS file of the 1-sigma error map (the image's file when only
        ``error_hdu`` was given), or None.
    error_hdu : int, str or None
        The HDU of the error map; None: its first HDU with 2-D image data.
    weight : `~pathlib.Path` or None
        The FITS file of the inverse-variance weight map, or None.
    weight_hdu : int, str or None
        The HDU of the weight map; None: its first HDU with 2-D image data.
    unit : `~astropy.units.UnitBase` or None
        The unit of the image (and its error map) given in the
        configuration; None: the header's ``BUNIT``, or dimensionless
        without one.
    """

    image: Path
    hdu: int | str | None = None
    error: Path | None = None
    error_hdu: int | str | None = None
    weight: Path | None = None
    weight_hdu: int | str | None = None
    unit: u.UnitBase | None = None


@dataclass(frozen=True)
class BandSpec:
    """One band, as given in ``[bands.<band>]``.

    Attributes
    ----------
    name : str
        The band name (e.g. ``"F150W"``).
    psf : `~pathlib.Path` or None
        The FITS file of the PSF image, or None.
    psf_hdu : int, str or None
        The HDU of the PSF image; None: the first HDU with 2-D image data.
    psf_fwhm : `~astropy.units.Quantity` or None
        The FWHM (an angle) of a Gaussian PSF, or None. With neither
        ``psf`` nor ``psf_fwhm`` the FWHM is fitted to the sources.
    psf_oversampling : int, tuple of int or None
        Oversampling of the PSF image (``psf_oversampling``, else the
        ``OVERSAMP`` keyword of a WebbPSF / STPSF file), or None (detector
        sampled).
    """

    name: str
    psf: Path | None = None
    psf_hdu: int | str | None = None
    psf_fwhm: u.Quantity | None = None
    psf_oversampling: int | tuple | None = None


@dataclass(frozen=True)
class ArcSpec:
    """One lens arc: its images and optional cutout (``[arcs.<arc>]``).

    Attributes
    ----------
    name : str
        ``"L1"`` or ``"L2"``.
    images : dict of str to `ImageSpec`
        The image of every band, in the order of ``[bands]``.
    cutout_center : `~astropy.coordinates.SkyCoord` or None
        The centre of the cutout (ICRS), or None for the whole images.
    cutout_size : `~astropy.units.Quantity` or None
        The size of the cutout: a scalar angle (square) or two angles
        (ny, nx), as for `~astropy.nddata.Cutout2D`; None without a cutout.
    """

    name: str
    images: dict
    cutout_center: SkyCoord | None = None
    cutout_size: u.Quantity | None = None


@dataclass(frozen=True)
class ParametricSpec:
    """Parametric lens models to compare with (``[parametric]``).

    Attributes
    ----------
    lenstool : `~pathlib.Path` or None
        A Lenstool parameter file (``best.par``), or None.
    fit : bool
        Whether to fit a lenstronomy model to the pairs.
    model : tuple of str
        The lenstronomy profiles of that fit.
    z_lens, z_source : float or None
        Lens and source redshifts (given whenever ``fit`` is true or
        ``lenstool`` is set; ``0 < z_lens < z_source``).
    sigma_pos : `~astropy.units.Quantity`
        Positional error of the fit's chi-square (default 0.01 arcsec: a
        smooth parametric model is not expected to place images better than
        that, whatever the astrometric errors).
    centre : `~astropy.coordinates.SkyCoord` or None
        Origin of the fit's frame, e.g. the brightest cluster galaxy; None:
        the Lenstool model's frame when one is given, else the pairs' frame.
    fix_centre : bool
        Hold the centre of the fit's first profile at the origin of its frame
        (``centre``, which is then required), e.g. on the BCG.
    """

    lenstool: Path | None = None
    fit: bool = False
    model: tuple = _DEFAULT_MODEL
    z_lens: float | None = None
    z_source: float | None = None
    sigma_pos: u.Quantity = 0.01 * u.arcsec
    centre: SkyCoord | None = None
    fix_centre: bool = False


@dataclass(frozen=True)
class KnotSpec:
    """A catalogue-only run on a knot constellation (``[knots]``).

    Attributes
    ----------
    catalogue : `~pathlib.Path`
        The multiple-image catalogue (Lenstool format, or ECSV).
    macro_images : tuple of str
        The names of the macro-images.
    centres : dict or None
        ``{name: SkyCoord}`` given in the configuration; None: read from the
        commented lines of the catalogue (when an assignment needs them).
    systems : tuple
        ``("range", lo, hi)`` (integer system ids in ``[lo, hi)``),
        ``("names", name, ...)``, or ``()`` for every system.
    assign : str
        ``"centre"``, ``"mapping"`` or ``"model"``.
    mapping : `~pathlib.Path` or None
        ECSV table with columns ``id`` and ``macro``.
    models : tuple of `~pathlib.Path`
        Lenstool models to compare with (the first assigns when ``assign =
        "model"``).
    z_source : float or None
        Redshift of the knots (None: from the catalogue).
    sigma_pos : `~astropy.units.Quantity` or str
        Position error, or ``"auto"`` (measured per pair of macro-images).
    """

    catalogue: Path
    macro_images: tuple
    centres: dict | None = None
    systems: tuple = ()
    assign: str = "centre"
    mapping: Path | None = None
    models: tuple = ()
    z_source: float | None = None
    sigma_pos: u.Quantity | str = "auto"

    def knot_filter(self):
        """The ``knots`` argument of :func:`~lensdual.pairing.pairs_from_knots`."""
        if not self.systems:
            return None
        if self.systems[0] == "range":
            lo, hi = self.systems[1:]

            def in_range(name):
                try:
                    return lo <= int(name) < hi
                except ValueError:
                    return False

            return in_range
        return list(self.systems[1:])


@dataclass(frozen=True)
class RunConfig:
    """A validated configuration of ``lensdual run``, as made by :func:`load_config`.

    All paths are absolute and resolved (symbolic links followed).

    Attributes
    ----------
    path : `~pathlib.Path`
        The configuration file.
    outdir : `~pathlib.Path`
        The output directory (it may not exist yet).
    bands : dict of str to `BandSpec`
        The bands, in the order of the file.
    arcs : dict of str to `ArcSpec`
        ``{"L1": ..., "L2": ...}``.
    catalogs : dict of str to `~pathlib.Path` or None
        ``{"L1": path, "L2": path}`` of the point-source catalogues to use
        instead of the detection, or None.
    pairing_method : str
        ``"auto"`` or ``"manual"``.
    pairs_file : `~pathlib.Path` or None
        The ECSV table of (id1, id2) pairs (manual pairing only).
    estimator : str
        The size-magnification estimator, a key of
        `lensdual.estimators.METHODS`.
    sigma_pos : `~astropy.units.Quantity` or str
        The positional error of the sources (an angle), or ``"auto"`` for
        the errors of the PSF fits.
    n_bootstrap : int
        Number of bootstrap resamplings.
    snr_threshold : float
        Significance threshold of a duality violation.
    seed : int
        Seed of the random numbers.
    null_realisations : int
        Realisations of :func:`lensdual.duality.null_calibration` (0: off).
    parametric : `ParametricSpec` or None
        The ``[parametric]`` table, or None without one.
    knots : `KnotSpec` or None
        The ``[knots]`` table of a catalogue-only run (then ``bands`` and
        ``arcs`` are empty), or None.
    """

    path: Path
    outdir: Path
    bands: dict
    arcs: dict
    catalogs: dict | None = None
    pairing_method: str = "auto"
    pairs_file: Path | None = None
    estimator: str = "adaptive"
    sigma_pos: u.Quantity | str = "auto"
    n_bootstrap: int = 1000
    snr_threshold: float = 3.0
    seed: int = 0
    null_realisations: int = 0
    parametric: ParametricSpec | None = None
    knots: KnotSpec | None = None


# ---------------------------------------------------------------------------
# small helpers
# ---------------------------------------------------------------------------

_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")
_ESCAPES = {"\b": r"\b", "\t": r"\t", "\n": r"\n", "\f": r"\f", "\r": r"\r", '"': r"\"",
            "\\": r"\\"}


def _toml_string(text):
    """``text`` as a TOML basic string."""
    out = []
    for ch in text:
        if ch in _ESCAPES:
            out.append(_ESCAPES[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _toml_key(key):
    """``key`` as a TOML key: bare when it can be, else quoted."""
    return key if _BARE_KEY.match(key) else _toml_string(key)


def _sec(*parts):
    """The TOML name of a table, e.g. ``arcs.L1.F150W``."""
    return ".".join(_toml_key(str(p)) for p in parts)


def _suggest(word, options, fmt="'{}'"):
    """`` (did you mean 'x'?)`` for the option closest to ``word``, or ``""``."""
    match = difflib.get_close_matches(str(word), [str(o) for o in options], n=1, cutoff=0.6)
    return f" (did you mean {fmt.format(match[0])}?)" if match else ""


def _describe(value):
    """A short description of a TOML value for error messages."""
    if isinstance(value, bool):
        return f"a boolean ({str(value).lower()})"
    if isinstance(value, int):
        return f"an integer ({value})"
    if isinstance(value, float):
        return f"a float ({value!r})"
    if isinstance(value, str):
        return f"a string ({value!r})"
    if isinstance(value, list):
        return "an array"
    if isinstance(value, dict):
        return "a table"
    return f"a {type(value).__name__} ({value})"


def _parse_angle(value):
    """``(Quantity, None)`` for an angle string, else ``(None, message)``."""
    if not isinstance(value, str):
        return None, f"expected an angle string such as \"0.01 arcsec\", got {_describe(value)}"
    try:
        q = u.Quantity(value)
    except (TypeError, ValueError):
        return None, (f"could not read {value!r} as an angle (a number and an angular unit, "
                      "e.g. \"0.01 arcsec\" or \"10 mas\")")
    if q.unit == u.dimensionless_unscaled:
        return None, (f"{value!r} has no unit: give an angle with its unit, "
                      f"like \"{value.strip()} arcsec\"")
    if q.unit.physical_type != "angle":
        return None, f"{value!r} is not an angle (its unit {q.unit} is a {q.unit.physical_type})"
    if not q.isscalar:
        return None, f"{value!r} is not a single angle"
    if not np.isfinite(q.value):
        return None, f"{value!r} is not finite"
    return q, None


_PLAIN_PAIR = re.compile(r"^\s*[-+]?[\d.]+(?:[eE][-+]?\d+)?[\s,]+[-+]?[\d.]+(?:[eE][-+]?\d+)?\s*$")


def _parse_center(value):
    """``(SkyCoord, None)`` for a sky position string, else ``(None, message)``."""
    if not isinstance(value, str):
        return None, (f"expected a sky position string such as \"110.8 -73.45\", "
                      f"got {_describe(value)}")
    if _PLAIN_PAIR.match(value):
        units = u.deg
    elif ":" in value:
        units = (u.hourangle, u.deg)
    else:
        units = None
    kwargs = {} if units is None else {"unit": units}
    try:
        return SkyCoord(value.replace(",", " ") if units is u.deg else value,
                        frame="icrs", **kwargs), None
    except (ValueError, TypeError, u.UnitsError):
        return None, (f"could not read {value!r} as a sky position (ICRS \"RA Dec\": in "
                      "degrees as \"110.8 -73.45\", or as \"07h23m12s -73d27m00s\" or "
                      "\"07:23:12 -73:27:00\")")


def _parse_unit(value):
    """``(unit, None)`` or ``(None, message)``."""
    try:
        return u.Unit(value, parse_strict="raise"), None
    except (ValueError, TypeError):
        return None, f"{value!r} is not a valid astropy unit"


def _hdu_label(hdu):
    return f"HDU {hdu}" if isinstance(hdu, int) else f"HDU {hdu!r}"


def _hdu_names(hdul):
    return ", ".join(f"{i} {h.name!r}" if h.name else str(i) for i, h in enumerate(hdul))


def _is_2d_image(hdu):
    return bool(hdu.is_image) and len(hdu.shape) == 2


class _HDUError(ValueError):
    """A requested HDU does not exist or holds no 2-D image (``on_hdu_key``: blame the hdu key)."""

    def __init__(self, message, on_hdu_key):
        super().__init__(message)
        self.on_hdu_key = on_hdu_key


def _find_hdu(hdul, hdu, path):
    """Index of the requested HDU of ``hdul`` (the first 2-D image for None)."""
    if hdu is None:
        for i, h in enumerate(hdul):
            if _is_2d_image(h):
                return i
        raise _HDUError(f"{path} has no HDU with 2-D image data (HDUs: {_hdu_names(hdul)})"
                        + _cube_hint(hdul), on_hdu_key=False)
    if isinstance(hdu, int):
        if hdu >= len(hdul):
            n = len(hdul)
            raise _HDUError(f"{_hdu_label(hdu)} does not exist in {path} "
                            f"({n} HDU{'' if n == 1 else 's'}: {_hdu_names(hdul)})",
                            on_hdu_key=True)
        index = hdu
    else:
        try:
            index = hdul.index_of(hdu)
        except KeyError:
            hint = _suggest(hdu.upper(), [h.name for h in hdul if h.name])
            raise _HDUError(f"{_hdu_label(hdu)} does not exist in {path}{hint} "
                            f"(HDUs: {_hdu_names(hdul)})", on_hdu_key=True) from None
    h = hdul[index]
    if not _is_2d_image(h):
        if not h.is_image:
            what = "a table"
        else:
            what = f"{len(h.shape)}-D data" if h.shape else "no data"
        raise _HDUError(f"{_hdu_label(hdu)} of {path} has no 2-D image data (it has {what})"
                        + _cube_hint(hdul), on_hdu_key=True)
    return index


def _cube_hint(hdul):
    """Words on the image HDUs that are cubes (their shapes, and what to do)."""
    cubes = [(i, h.shape) for i, h in enumerate(hdul) if h.is_image and len(h.shape or ()) > 2]
    if not cubes:
        return ""
    listed = ", ".join(f"HDU {i} has shape {shape}" for i, shape in cubes)
    single = any(all(n == 1 for n in shape[:-2]) for _, shape in cubes)
    return (f"; {listed}" + (": a cube of one plane; write that plane as a 2-D image (e.g. "
                            "data[0] with the celestial WCS, wcs.celestial)" if single else
                            ": a cube; write the plane of the band as a 2-D image"))


def _header_wcs(header, hdul):
    """The WCS of ``header`` (lookup tables from ``hdul``), without FITSFixedWarning noise."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FITSFixedWarning)
        return WCS(header, hdul)


def _cutout(shape, wcs, center, size):
    """`~astropy.nddata.Cutout2D` of an array of ``shape`` (no data is read)."""
    dummy = np.broadcast_to(np.int8(0), shape)
    return Cutout2D(dummy, center, size, wcs=wcs, mode="trim", copy=False)


def _psf_oversampling(path, hdu):
    """The oversampling a PSF file declares (WebbPSF / STPSF ``OVERSAMP``; 1 for their
    detector-sampled ``DET_SAMP`` extension), or None."""
    try:
        with fits.open(path) as hdul:
            index = _find_hdu(hdul, hdu, path)
            header = hdul[index].header
            if str(header.get("EXTNAME", "")).upper().startswith("DET_"):
                return None
            value = header.get("OVERSAMP", hdul[0].header.get("OVERSAMP"))
    except Exception:  # unreadable: reported elsewhere
        return None
    if isinstance(value, (int, float)) and not isinstance(value, bool) and value > 1 and \
            float(value).is_integer():
        return int(value)
    return None


def _read_psf(path, hdu):
    """The PSF image, normalised to unit sum; ValueError if unusable."""
    with fits.open(path, memmap=False) as hdul:
        index = _find_hdu(hdul, hdu, path)
        arr = np.array(hdul[index].data, dtype=np.float64)
    ny, nx = arr.shape
    if ny % 2 == 0 or nx % 2 == 0 or min(ny, nx) < _MIN_PSF_SIZE:
        raise ValueError(f"the PSF image in {path} must have an odd shape of at least "
                         f"{_MIN_PSF_SIZE}x{_MIN_PSF_SIZE} pixels (centred on its central "
                         f"pixel), got {ny}x{nx}")
    if not np.isfinite(arr).all():
        raise ValueError(f"the PSF image in {path} contains NaN or infinite values")
    total = arr.sum()
    if not total > 0:
        raise ValueError(f"the PSF image in {path} must have a positive sum, got {total}")
    return arr / total


# ---------------------------------------------------------------------------
# validation
# ---------------------------------------------------------------------------


@dataclass
class _ImageInfo:
    """What the validation learnt about an image HDU."""

    shape: tuple
    wcs: WCS | None
    bunit: str | None
    unit: u.UnitBase | None = None
    path: Path | None = None


class _Validator:
    """Checks a parsed TOML document and collects every problem."""

    def __init__(self, data, path, outdir):
        self.data = data
        self.path = path
        self.base = path.parent
        self.outdir_arg = outdir
        self.problems = []
        self.band_names = []
        self.infos = {}  # (arc, band) -> _ImageInfo of the images read

    def add(self, message):
        self.problems.append(message)

    # --- generic checks -------------------------------------------------

    def unknown_keys(self, table, allowed, sec):
        for key in table:
            if key not in allowed:
                hint = _suggest(key, allowed)
                if not hint and allowed:
                    hint = f" (known keys: {', '.join(allowed)})"
                self.add(f"[{sec}] {_toml_key(key)}: unknown key{hint}")

    def section(self, name):
        """The top-level table ``name``: a dict, or None when absent or not a table."""
        value = self.data.get(name, _ABSENT)
        if value is _ABSENT:
            return None
        if not isinstance(value, dict):
            self.add(f"[{name}]: expected a table, got {_describe(value)}")
            return None
        return value

    def get_str(self, table, key, sec, default=_ABSENT, choices=None):
        value = table.get(key, _ABSENT)
        if value is _ABSENT:
            return default
        if not isinstance(value, str):
            self.add(f"[{sec}] {key}: expected a string, got {_describe(value)}")
            return _BAD
        if choices is not None and value not in choices:
            listed = ", ".join(f"'{c}'" for c in choices)
            self.add(f"[{sec}] {key}: {value!r} is not one of {listed}{_suggest(value, choices)}")
            return _BAD
        return value

    def get_int(self, table, key, sec, default, minimum):
        value = table.get(key, _ABSENT)
        if value is _ABSENT:
            return default
        if isinstance(value, bool) or not isinstance(value, int):
            self.add(f"[{sec}] {key}: expected an integer, got {_describe(value)}")
            return _BAD
        if value < minimum:
            self.add(f"[{sec}] {key}: must be >= {minimum}, got {value}")
            return _BAD
        return value

    def get_real(self, table, key, sec, default=_ABSENT, above=None):
        value = table.get(key, _ABSENT)
        if value is _ABSENT:
            return default
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.add(f"[{sec}] {key}: expected a number, got {_describe(value)}")
            return _BAD
        value = float(value)
        if not math.isfinite(value):
            self.add(f"[{sec}] {key}: must be finite, got {value}")
            return _BAD
        if above is not None and not value > above:
            self.add(f"[{sec}] {key}: must be > {above:g}, got {value:g}")
            return _BAD
        return value

    def get_bool(self, table, key, sec, default):
        value = table.get(key, _ABSENT)
        if value is _ABSENT:
            return default
        if not isinstance(value, bool):
            self.add(f"[{sec}] {key}: expected a boolean (true or false), got {_describe(value)}")
            return _BAD
        return value

    def get_angle(self, table, key, sec, default=_ABSENT, prefix=""):
        value = table.get(key, _ABSENT)
        if value is _ABSENT:
            return default
        q, message = _parse_angle(value)
        if q is None:
            self.add(f"[{sec}] {key}: {prefix}{message}")
            return _BAD
        if not q.value > 0:
            self.add(f"[{sec}] {key}: must be > 0, got {value!r}")
            return _BAD
        return q

    def get_hdu(self, table, key, sec):
        value = table.get(key, _ABSENT)
        if value is _ABSENT:
            return None
        if isinstance(value, bool) or not isinstance(value, (int, str)):
            self.add(f"[{sec}] {key}: expected an HDU index (integer >= 0) or EXTNAME (string), "
                     f"got {_describe(value)}")
            return _BAD
        if isinstance(value, int) and value < 0:
            self.add(f"[{sec}] {key}: an HDU index must be >= 0, got {value}")
            return _BAD
        if isinstance(value, str) and not value.strip():
            self.add(f"[{sec}] {key}: the EXTNAME must not be empty")
            return _BAD
        return value

    def get_file(self, table, key, sec):
        """An existing file named by ``table[key]``, resolved against the config directory."""
        value = table.get(key, _ABSENT)
        if value is _ABSENT:
            return None
        if not isinstance(value, str):
            self.add(f"[{sec}] {key}: expected a file path (string), got {_describe(value)}")
            return _BAD
        if not value.strip():
            self.add(f"[{sec}] {key}: the file path must not be empty")
            return _BAD
        path = self.resolve(value)
        if not path.exists():
            self.add(f"[{sec}] {key}: file not found: {path}")
            return _BAD
        if not path.is_file():
            self.add(f"[{sec}] {key}: not a file: {path}")
            return _BAD
        return path

    def resolve(self, value):
        return (self.base / Path(value).expanduser()).resolve()

    def inspect_fits(self, path, hdu, sec, file_key, hdu_key, *, celestial=False):
        """Open ``path`` lazily and check the HDU; an `_ImageInfo` or None."""
        try:
            hdul = fits.open(path)
        except Exception as exc:  # any failure means the file is unusable
            self.add(f"[{sec}] {file_key}: {path} is not a readable FITS file ({exc})")
            return None
        with hdul:
            try:
                index = _find_hdu(hdul, hdu, path)
                header = hdul[index].header
                shape = tuple(hdul[index].shape)
            except _HDUError as exc:
                self.add(f"[{sec}] {hdu_key if exc.on_hdu_key else file_key}: {exc}")
                return None
            except Exception as exc:
                self.add(f"[{sec}] {file_key}: {path} is not a readable FITS file ({exc})")
                return None
            wcs = None
            if celestial:
                where = f"{_hdu_label(index)} of {path}"
                try:
                    wcs = _header_wcs(header, hdul)
                except Exception as exc:
                    self.add(f"[{sec}] {file_key}: the WCS in the header of {where} is "
                             f"invalid ({exc})")
                    return None
                if not wcs.has_celestial:
                    self.add(f"[{sec}] {file_key}: the header of {where} has no celestial "
                             "WCS (RA/Dec axes), which is needed to pair the arcs on the sky")
                    return None
                wcs = wcs.celestial
            bunit = header.get("BUNIT")
            bunit = bunit.strip() if isinstance(bunit, str) else None
        return _ImageInfo(shape=shape, wcs=wcs, bunit=bunit)

    # --- tables ---------------------------------------------------------

    def check_root(self):
        for key, value in self.data.items():
            if key in _KEYS:
                continue
            owner = [s for s, keys in _KEYS.items() if key in keys]
            if not isinstance(value, dict) and owner:
                self.add(f"{_toml_key(key)}: unknown top-level key (it belongs in [{owner[0]}])")
            elif isinstance(value, dict):
                self.add(f"[{_toml_key(key)}]: unknown table"
                         f"{_suggest(key, list(_KEYS), fmt='[{}]')}")
            else:
                self.add(f"{_toml_key(key)}: unknown top-level key (the top level holds only "
                         f"the tables {', '.join(f'[{k}]' for k in _KEYS)})")

    def output(self):
        table = self.section("output") or {}
        self.unknown_keys(table, _KEYS["output"], "output")
        value = self.get_str(table, "outdir", "output", default=_DEFAULT_OUTDIR)
        if value is not _BAD and not value.strip():
            self.add("[output] outdir: must not be empty")
            value = _BAD
        if self.outdir_arg is not None:
            where = "outdir (argument)"
            path = Path(self.outdir_arg).expanduser().resolve()
        elif value is _BAD:
            return None
        else:
            where = "[output] outdir"
            path = self.resolve(value)
        if path.exists() and not path.is_dir():
            self.add(f"{where}: {path} exists and is not a directory")
        return path

    def analysis(self):
        table = self.section("analysis") or {}
        sec = "analysis"
        self.unknown_keys(table, _KEYS[sec], sec)
        out = {"estimator": self.get_str(table, "estimator", sec, "adaptive",
                                         choices=list(METHODS))}
        sigma = table.get("sigma_pos", "auto")
        if not isinstance(sigma, str):
            self.add(f'[{sec}] sigma_pos: expected "auto" or an angle string such as '
                     f'"0.01 arcsec", got {_describe(sigma)}')
            sigma = _BAD
        elif sigma != "auto":
            sigma = self.get_angle(table, "sigma_pos", sec, prefix='expected "auto" or an angle; ')
        out["sigma_pos"] = sigma
        out["n_bootstrap"] = self.get_int(table, "n_bootstrap", sec, 1000, minimum=10)
        out["snr_threshold"] = self.get_real(table, "snr_threshold", sec, 3.0, above=0)
        out["seed"] = self.get_int(table, "seed", sec, 0, minimum=0)
        null = self.get_int(table, "null_realisations", sec, 0, minimum=0)
        if null is not _BAD and 0 < null < 100:
            self.add(f"[{sec}] null_realisations: must be 0 (off) or >= 100, got {null}")
            null = _BAD
        elif null is not _BAD and null and out["estimator"] not in ("adaptive", _BAD):
            self.add(f"[{sec}] null_realisations: the null calibration needs "
                     f'estimator = "adaptive", got estimator = "{out["estimator"]}"')
            null = _BAD
        out["null_realisations"] = null
        return out

    def bands(self):
        table = self.section("bands")
        if table is None:
            if "bands" not in self.data:
                self.add("[bands]: missing: declare at least one band, e.g. a table "
                         '[bands.F150W] with psf_fwhm = "0.07 arcsec"')
            return {}
        if not table:
            self.add("[bands]: no bands declared (add a table such as [bands.F150W])")
        bands = {}
        for name, spec in table.items():
            sec = _sec("bands", name)
            if name == _CUTOUT:
                self.add(f"[{sec}]: 'cutout' is reserved (the cutout table of an arc) and "
                         "cannot be a band name")
                continue
            self.band_names.append(name)
            if not isinstance(spec, dict):
                self.add(f"[bands] {_toml_key(name)}: expected a table [{sec}], "
                         f"got {_describe(spec)}")
                continue
            self.unknown_keys(spec, _BAND_KEYS, sec)
            psf = self.get_file(spec, "psf", sec)
            psf_hdu = self.get_hdu(spec, "psf_hdu", sec)
            fwhm = self.get_angle(spec, "psf_fwhm", sec, default=None)
            if "psf" in spec and "psf_fwhm" in spec:
                self.add(f"[{sec}] psf_fwhm: give either psf (a PSF image) or psf_fwhm "
                         "(a Gaussian FWHM), not both")
            if "psf_hdu" in spec and "psf" not in spec:
                self.add(f"[{sec}] psf_hdu: given without psf")
            if psf is not None and psf is not _BAD and psf_hdu is not _BAD:
                if self.inspect_fits(psf, psf_hdu, sec, "psf", "psf_hdu") is not None:
                    try:
                        _read_psf(psf, psf_hdu)
                    except Exception as exc:
                        self.add(f"[{sec}] psf: {exc}")
            over = self.oversampling(spec, sec, psf, psf_hdu)
            bands[name] = BandSpec(name=name, psf=psf, psf_hdu=psf_hdu, psf_fwhm=fwhm,
                                   psf_oversampling=over)
        return bands

    def oversampling(self, spec, sec, psf, psf_hdu):
        value = spec.get("psf_oversampling", _ABSENT)
        if value is _ABSENT:
            if psf is None or psf is _BAD or psf_hdu is _BAD:
                return None
            return _psf_oversampling(psf, psf_hdu)
        if "psf" not in spec:
            self.add(f"[{sec}] psf_oversampling: given without psf (a PSF image)")
            return _BAD
        ok = (isinstance(value, int) and not isinstance(value, bool) and value >= 1) or (
            isinstance(value, list) and len(value) == 2
            and all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in value))
        if not ok:
            self.add(f"[{sec}] psf_oversampling: expected an integer >= 1 or [oy, ox], got "
                     f"{_describe(value)}")
            return _BAD
        return value if isinstance(value, int) else tuple(value)

    def arcs(self):
        table = self.section("arcs")
        if table is None:
            if "arcs" not in self.data:
                self.add("[arcs]: missing: arcs L1 and L2 are both required (tables "
                         "[arcs.L1.<band>] and [arcs.L2.<band>] for every band)")
            return {}
        for name in table:
            if name not in _ARCS:
                self.add(f"[{_sec('arcs', name)}]: unknown arc{_suggest(name, _ARCS)} "
                         "(the arcs are L1 and L2)")
        arcs = {}
        for arc in _ARCS:
            if arc not in table:
                self.add(f"[arcs.{arc}]: missing (arcs L1 and L2 are both required)")
                continue
            if not isinstance(table[arc], dict):
                self.add(f"[arcs] {arc}: expected a table, got {_describe(table[arc])}")
                continue
            arcs[arc] = self.arc(arc, table[arc])
        self.same_units()
        return arcs

    def arc(self, arc, table):
        center = size = None
        if _CUTOUT in table:
            center, size = self.cutout(arc, table[_CUTOUT])
        infos, images = {}, {}
        for band, spec in table.items():
            if band == _CUTOUT:
                continue
            sec = _sec("arcs", arc, band)
            if self.band_names and band not in self.band_names:
                self.add(f"[{sec}]: {band!r} is not a band declared in [bands]"
                         f"{_suggest(band, self.band_names)}")
                continue
            if not isinstance(spec, dict):
                self.add(f"[arcs.{arc}] {_toml_key(band)}: expected a table [{sec}], "
                         f"got {_describe(spec)}")
                continue
            images[band], infos[band] = self.image(spec, sec)
        for band in self.band_names:
            if band not in table:
                self.add(f"[{_sec('arcs', arc, band)}]: missing: band {band!r} is declared in "
                         f"[bands] but arc {arc} has no image in it")
        if center is not None and size is not None and _valid(center, size):
            outside = []
            for band, info in infos.items():
                if info is None:
                    continue
                try:
                    _cutout(info.shape, info.wcs, center, size)
                except NoOverlapError:
                    outside.append(band)
                except Exception as exc:
                    self.add(f"[arcs.{arc}.cutout]: cannot cut out the image of band "
                             f"{band} ({exc})")
            if outside:
                which = "image of band" if len(outside) == 1 else "images of bands"
                files = ", ".join(str(images[b].image) for b in outside if images[b] is not None)
                self.add(f"[arcs.{arc}.cutout] center: the cutout does not overlap the {which} "
                         f"{', '.join(outside)} ({files})")
        self.same_grid(arc, infos)
        self.infos.update({(arc, b): i for b, i in infos.items() if i is not None})
        images = {b: images[b] for b in self.band_names if images.get(b) is not None}
        return ArcSpec(name=arc, images=images, cutout_center=center, cutout_size=size)

    def same_grid(self, arc, infos):
        """All bands of an arc must share one pixel grid (they are stacked pixel by pixel)."""
        given = [(b, i) for b, i in infos.items() if i is not None and i.wcs is not None]
        if len(given) < 2:
            return
        ref_band, ref = given[0]
        ny, nx = ref.shape[-2:]
        corners = np.array([[0, 0], [nx - 1, 0], [0, ny - 1], [nx - 1, ny - 1],
                            [(nx - 1) / 2, (ny - 1) / 2]], dtype=float)
        world = ref.wcs.pixel_to_world(corners[:, 0], corners[:, 1])
        for band, info in given[1:]:
            if info.shape != ref.shape:
                why = f"shape {info.shape} against {ref.shape}"
            else:
                px, py = info.wcs.world_to_pixel(world)
                off = float(np.max(np.hypot(px - corners[:, 0], py - corners[:, 1])))
                if not off > _GRID_TOLERANCE:
                    continue
                why = f"its WCS puts the same sky up to {off:.3g} pixels elsewhere"
            self.add(f"[{_sec('arcs', arc, band)}] image: its pixel grid differs from band "
                     f"{ref_band}'s ({why}). lensdual stacks the bands of an arc pixel by "
                     f"pixel, so they must share one grid: resample {info.path} onto the grid "
                     f"of {ref.path} first (e.g. reproject.reproject_interp)")

    def same_units(self):
        """Flux ratios and colours need every image in convertible units."""
        units = {key: info.unit for key, info in self.infos.items() if info.unit is not None}
        if not units:
            return
        ref_key, ref = next(iter(units.items()))
        for (arc, band), unit in units.items():
            if not unit.is_equivalent(ref):
                self.add(f"[{_sec('arcs', arc, band)}] unit: {unit} (from "
                         f"{'unit' if self.given_unit(arc, band) else 'BUNIT'}) cannot be "
                         f"converted to {ref} of [arcs.{ref_key[0]}.{ref_key[1]}]: flux ratios "
                         "and colours need all images in convertible units (a typo?)")

    def given_unit(self, arc, band):
        try:
            return "unit" in self.data["arcs"][arc][band]
        except (KeyError, TypeError):
            return False

    def cutout(self, arc, table):
        sec = f"arcs.{arc}.cutout"
        if not isinstance(table, dict):
            self.add(f"[arcs.{arc}] cutout: expected a table [{sec}], got {_describe(table)}")
            return _BAD, _BAD
        self.unknown_keys(table, _CUTOUT_KEYS, sec)
        center = size = _BAD
        if "center" not in table:
            self.add(f'[{sec}] center: missing (the sky position, e.g. "110.8 -73.45")')
        else:
            center, message = _parse_center(table["center"])
            if center is None:
                self.add(f"[{sec}] center: {message}")
                center = _BAD
        value = table.get("size", _ABSENT)
        if value is _ABSENT:
            self.add(f'[{sec}] size: missing (an angle, e.g. "6 arcsec", or two: [ny, nx])')
        elif isinstance(value, list):
            if len(value) != 2:
                self.add(f"[{sec}] size: expected one angle or a list of two (ny, nx), "
                         f"got a list of {len(value)}")
            else:
                parts = [self.get_angle({f"size[{i}]": v}, f"size[{i}]", sec)
                         for i, v in enumerate(value)]
                if _valid(*parts):
                    size = u.Quantity([p.to(u.arcsec) for p in parts])
        else:
            size = self.get_angle(table, "size", sec)
        return center, size

    def image(self, table, sec):
        self.unknown_keys(table, _IMAGE_KEYS, sec)
        if "image" not in table:
            self.add(f"[{sec}] image: missing (the FITS file of the image)")
            image = _BAD
        else:
            image = self.get_file(table, "image", sec)
        hdu = self.get_hdu(table, "hdu", sec)
        maps = {}
        for key in ("error", "weight"):
            path = self.get_file(table, key, sec)
            map_hdu = self.get_hdu(table, f"{key}_hdu", sec)
            if path is None and f"{key}_hdu" in table:
                path = image  # an extension of the image's own file
            maps[key] = (path, map_hdu)
        if maps["error"][0] is not None and maps["weight"][0] is not None:
            self.add(f"[{sec}] weight: give either error (a 1-sigma map) or weight (an "
                     "inverse-variance map), not both")
        elif maps["error"][0] is None and maps["weight"][0] is None and image not in (None, _BAD):
            # pipeline products (JWST *_i2d, HST *_drz / *_drc): the error or weight map
            # is an extension of the image's own file
            found = _product_map(image)
            if found is not None:
                maps[found[0]] = (image, found[1])
        unit = None
        if "unit" in table:
            if not isinstance(table["unit"], str):
                self.add(f"[{sec}] unit: expected a unit string such as \"nJy\", "
                         f"got {_describe(table['unit'])}")
                unit = _BAD
            else:
                unit, message = _parse_unit(table["unit"])
                if unit is None:
                    self.add(f"[{sec}] unit: {message}")
                    unit = _BAD
        info = None
        if image is not _BAD and hdu is not _BAD:
            info = self.inspect_fits(image, hdu, sec, "image", "hdu", celestial=True)
            if info is not None and unit is None and info.bunit:
                if _parse_unit(info.bunit)[0] is None:
                    self.add(f"[{sec}] image: the BUNIT {info.bunit!r} of {image} is "
                             'not a valid astropy unit; give the unit, e.g. unit = "nJy"')
            elif info is not None and unit not in (None, _BAD) and info.bunit:
                header_unit = _parse_unit(info.bunit)[0]
                if header_unit is not None and header_unit != unit:
                    self.add(f"[{sec}] unit: {table['unit']!r} is given, but the BUNIT of "
                             f"{image} says {info.bunit!r}; remove unit (the header is "
                             "right) or correct the header (a typo here scales the fluxes)")
        if unit is _BAD or info is None:
            image_unit = None  # unknown: its problem is already recorded
        elif unit is not None:
            image_unit = unit
        elif info.bunit:
            image_unit = _parse_unit(info.bunit)[0]
        else:
            image_unit = u.dimensionless_unscaled
        for key, (path, map_hdu) in maps.items():
            if path is None or path is _BAD or map_hdu is _BAD:
                continue
            map_info = self.inspect_fits(path, map_hdu, sec, key, f"{key}_hdu")
            if info is not None and map_info is not None and map_info.shape != info.shape:
                self.add(f"[{sec}] {key}: the {key} map in {path} has shape {map_info.shape}, "
                         f"the image {info.shape}")
            if key == "error" and map_info is not None and map_info.bunit:
                map_unit = _parse_unit(map_info.bunit)[0]
                if map_unit is None:
                    self.add(f"[{sec}] error: the BUNIT {map_info.bunit!r} of the error map "
                             f"{path} is not a valid astropy unit")
                elif image_unit is not None and not map_unit.is_equivalent(image_unit):
                    self.add(f"[{sec}] error: the error map {path} is in {map_unit} (its "
                             f"BUNIT), the image in {image_unit}: not convertible; give both "
                             "in one unit (e.g. convert MJy/sr to flux per pixel with the "
                             "pixel area, PIXAR_SR)")
        if not _valid(image, hdu, unit, *maps["error"], *maps["weight"]):
            return None, info
        spec = ImageSpec(image=image, hdu=hdu, error=maps["error"][0],
                         error_hdu=maps["error"][1], weight=maps["weight"][0],
                         weight_hdu=maps["weight"][1], unit=unit)
        if info is not None:
            info = _ImageInfo(shape=info.shape, wcs=info.wcs, bunit=info.bunit,
                              unit=image_unit, path=image)
        return spec, info

    def read_ecsv(self, path, loc):
        try:
            return Table.read(path, format="ascii.ecsv")
        except Exception as exc:  # any failure means the file is unusable
            self.add(f"{loc}: could not read {path} as an ECSV table ({exc})")
            return None

    def int_column(self, table, name, path, loc):
        """The values of integer column ``name``, or None (problem recorded)."""
        if name not in table.colnames:
            return None
        col = table[name]
        if getattr(col, "mask", None) is not None and np.any(col.mask):
            self.add(f"{loc}: column {name!r} of {path} has missing values")
            return None
        values = np.asarray(col)
        if values.ndim != 1 or not np.issubdtype(values.dtype, np.integer):
            self.add(f"{loc}: column {name!r} of {path} must hold integers, "
                     f"got dtype {values.dtype}")
            return None
        return values

    def catalogs(self):
        table = self.section("catalogs")
        if table is None:
            return None, {}
        self.unknown_keys(table, _ARCS, "catalogs")
        given = [arc for arc in _ARCS if arc in table]
        if len(given) == 1:
            missing = [arc for arc in _ARCS if arc not in table][0]
            self.add(f"[catalogs] {missing}: missing (give the catalogues of both arcs, L1 and "
                     f"L2, or neither; only {given[0]} is given)")
        paths, ids = {}, {}
        for arc in given:
            path = self.get_file(table, arc, "catalogs")
            paths[arc] = path
            if path is _BAD:
                continue
            ids[arc] = self.catalog(path, f"[catalogs] {arc}")
        if not given or len(given) == 1 or not _valid(*paths.values()):
            return None, ids
        return paths, ids

    def catalog(self, path, loc):
        tab = self.read_ecsv(path, loc)
        if tab is None:
            return None
        ids = None
        if "id" not in tab.colnames:
            self.add(f"{loc}: {path} has no 'id' column (columns: {', '.join(tab.colnames)})")
        else:
            ids = self.int_column(tab, "id", path, loc)
            if ids is not None:
                uniq, counts = np.unique(ids, return_counts=True)
                if (counts > 1).any():
                    self.add(f"{loc}: the ids in {path} must be unique; repeated: "
                             f"{uniq[counts > 1].tolist()}")
        if "sky" in tab.colnames:
            if not isinstance(tab["sky"], SkyCoord):
                self.add(f"{loc}: column 'sky' of {path} is not a SkyCoord")
        elif "ra" in tab.colnames and "dec" in tab.colnames:
            for name in ("ra", "dec"):
                col = tab[name]
                unit = getattr(col, "unit", None)
                if not np.issubdtype(np.asarray(col).dtype, np.number):
                    self.add(f"{loc}: column {name!r} of {path} is not numeric")
                elif unit is not None and unit.physical_type != "angle":
                    self.add(f"{loc}: column {name!r} of {path} has unit {unit}, not an angle")
        else:
            self.add(f"{loc}: {path} needs a SkyCoord column 'sky' or columns 'ra' and 'dec' "
                     f"(deg) (columns: {', '.join(tab.colnames)})")
        return None if ids is None else set(ids.tolist())

    def pairing(self, catalog_ids):
        table = self.section("pairing") or {}
        sec = "pairing"
        self.unknown_keys(table, _KEYS[sec], sec)
        method = self.get_str(table, "method", sec, "auto", choices=_PAIRING_METHODS)
        path = self.get_file(table, "file", sec)
        if method == "manual" and "file" not in table:
            self.add('[pairing] file: required when method = "manual" (an ECSV table with '
                     "integer columns id1, id2)")
        if method == "auto" and "file" in table:
            self.add('[pairing] file: a pairs file is only used with method = "manual" '
                     '(set method = "manual", or remove file)')
        if path is not None and path is not _BAD:
            self.pairs(path, catalog_ids)
        return method, path

    def pairs(self, path, catalog_ids):
        loc = "[pairing] file"
        tab = self.read_ecsv(path, loc)
        if tab is None:
            return
        missing = [c for c in ("id1", "id2") if c not in tab.colnames]
        if missing:
            self.add(f"{loc}: {path} lacks column(s) {', '.join(missing)} (columns: "
                     f"{', '.join(tab.colnames)})")
            return
        if len(tab) < _MIN_PAIRS:
            self.add(f"{loc}: {path} lists {len(tab)} pair(s); at least {_MIN_PAIRS} are needed")
        for name, arc in (("id1", "L1"), ("id2", "L2")):
            values = self.int_column(tab, name, path, loc)
            if values is None:
                continue
            uniq, counts = np.unique(values, return_counts=True)
            if (counts > 1).any():
                self.add(f"{loc}: {name} value(s) {uniq[counts > 1].tolist()} appear in more "
                         f"than one pair of {path}")
            known = catalog_ids.get(arc)
            if known is not None:
                unknown = sorted(set(values.tolist()) - known)
                if unknown:
                    self.add(f"{loc}: {name} value(s) {unknown} of {path} are not in the "
                             f"[catalogs] {arc} catalogue")

    def parametric(self):
        table = self.section("parametric")
        if table is None:
            return None
        sec = "parametric"
        self.unknown_keys(table, _KEYS[sec], sec)
        lenstool = self.get_file(table, "lenstool", sec)
        fit = self.get_bool(table, "fit", sec, False)
        model = self.model(table.get("model", _ABSENT))
        z_lens = self.get_real(table, "z_lens", sec, None, above=0)
        z_source = self.get_real(table, "z_source", sec, None, above=0)
        if fit is True or "lenstool" in table:
            why = "fit = true" if fit is True else "lenstool is given"
            for key, value in (("z_lens", z_lens), ("z_source", z_source)):
                if value is None:
                    self.add(f"[parametric] {key}: required when {why}")
        if isinstance(z_lens, float) and isinstance(z_source, float) and z_source <= z_lens:
            self.add(f"[parametric] z_source: must be larger than z_lens ({z_lens:g}), "
                     f"got {z_source:g}")
        sigma_pos = self.get_angle(table, "sigma_pos", sec, 0.01 * u.arcsec)
        centre = None
        if "centre" in table:
            centre, message = _parse_center(table["centre"])
            if centre is None:
                self.add(f"[parametric] centre: {message}")
        fix_centre = self.get_bool(table, "fix_centre", sec, False)
        if fix_centre is True and "centre" not in table:
            self.add("[parametric] fix_centre: needs centre (the sky position to hold the "
                     "first profile's centre at)")
        return ParametricSpec(lenstool=lenstool, fit=fit, model=model, z_lens=z_lens,
                              z_source=z_source, sigma_pos=sigma_pos, centre=centre,
                              fix_centre=fix_centre)

    def model(self, value):
        if value is _ABSENT:
            return _DEFAULT_MODEL
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            self.add("[parametric] model: expected a list of lenstronomy profile names "
                     f'(e.g. ["NFW_ELLIPSE_CSE", "SHEAR"]), got {_describe(value)}')
            return _BAD
        if not value:
            self.add("[parametric] model: the list of profiles is empty")
            return _BAD
        from ..parametric.fitting import PROFILE_DEFAULTS

        bad = [name for name in value if name not in PROFILE_DEFAULTS]
        for name in bad:
            self.add(f"[parametric] model: unsupported profile {name!r}"
                     f"{_suggest(name, list(PROFILE_DEFAULTS))} (supported: "
                     f"{', '.join(PROFILE_DEFAULTS)})")
        return _BAD if bad else tuple(value)

    # --- all ------------------------------------------------------------

    # --- a catalogue-only run -------------------------------------------

    def knots(self):
        table = self.section("knots")
        if table is None:
            return None
        sec = "knots"
        self.unknown_keys(table, _KEYS[sec], sec)
        extra = [f"[{t}]" for t in _IMAGE_TABLES if t in self.data]
        if extra:
            self.add(f"[knots]: a knot run is catalogue-only; remove {', '.join(extra)} (or "
                     "[knots] for a run on images)")
        catalogue = self.get_file(table, "catalogue", sec)
        if "catalogue" not in table:
            self.add("[knots] catalogue: required (a Lenstool multiple-image catalogue or an "
                     "ECSV table)")
        names = table.get("macro_images", _ABSENT)
        if names is _ABSENT:
            self.add('[knots] macro_images: required, e.g. ["1.1", "1.2", "1.3"]')
            names = _BAD
        elif (not isinstance(names, list) or len(names) < 2
              or not all(isinstance(n, str) and n for n in names)):
            self.add("[knots] macro_images: expected a list of at least 2 names, got "
                     f"{_describe(names)}")
            names = _BAD
        elif len(set(names)) != len(names):
            self.add(f"[knots] macro_images: repeated names in {names}")
            names = _BAD
        centres = self.knot_centres(table.get("centres", "catalogue"), names)
        systems = self.knot_systems(table.get("systems", _ABSENT))
        mapping = self.get_file(table, "mapping", sec)
        models = table.get("models", [])
        if isinstance(models, str):
            models = [models]
        if not isinstance(models, list) or not all(isinstance(m, str) for m in models):
            self.add(f"[knots] models: expected a list of Lenstool files, got {_describe(models)}")
            models = _BAD
        else:
            models = tuple(self.get_file({"models": m}, "models", sec) for m in models)
            models = models if _valid(*models) else _BAD
        default = "mapping" if "mapping" in table else "model" if models else "centre"
        assign = self.get_str(table, "assign", sec, default, choices=list(_ASSIGN))
        if assign == "mapping" and "mapping" not in table:
            self.add('[knots] mapping: required when assign = "mapping" (an ECSV table with '
                     "columns id, macro)")
        if assign == "model" and models == ():
            self.add('[knots] models: assign = "model" needs at least one Lenstool model')
        if mapping not in (None, _BAD):
            tab = self.read_ecsv(mapping, "[knots] mapping")
            if tab is not None and not {"id", "macro"} <= set(tab.colnames):
                self.add(f"[knots] mapping: {mapping} needs columns 'id' and 'macro', has "
                         f"{tab.colnames}")
        z_source = self.get_real(table, "z_source", sec, None, above=0)
        sigma = table.get("sigma_pos", "auto")
        if sigma != "auto":
            sigma = self.get_angle(table, "sigma_pos", sec,
                                   prefix='expected "auto" or an angle; ')
        if not _valid(catalogue, names, centres, systems, mapping, models, assign, z_source,
                      sigma):
            return _BAD
        return KnotSpec(catalogue=catalogue, macro_images=tuple(names), centres=centres,
                        systems=systems, assign=assign, mapping=mapping, models=models,
                        z_source=z_source, sigma_pos=sigma)

    def knot_centres(self, value, names):
        if value == "catalogue":
            return None
        if not isinstance(value, dict):
            self.add('[knots] centres: expected "catalogue" or a table {name = "RA Dec"}, got '
                     f"{_describe(value)}")
            return _BAD
        centres = {}
        for name, text in value.items():
            centre, message = _parse_center(text)
            if centre is None:
                self.add(f"[knots.centres] {_toml_key(name)}: {message}")
                return _BAD
            centres[name] = centre
        if names is not _BAD and set(centres) != set(names):
            self.add(f"[knots] centres: give a centre for every macro-image {names}, got "
                     f"{sorted(centres)}")
            return _BAD
        return None if names is _BAD else {n: centres[n] for n in names}

    def knot_systems(self, value):
        if value is _ABSENT:
            return ()
        if (isinstance(value, list) and len(value) == 2
                and all(isinstance(v, int) and not isinstance(v, bool) for v in value)):
            if not value[0] < value[1]:
                self.add(f"[knots] systems: the range [lo, hi) needs lo < hi, got {value}")
                return _BAD
            return ("range", value[0], value[1])
        if isinstance(value, list) and value and all(isinstance(v, str) for v in value):
            return ("names", *value)
        self.add("[knots] systems: expected [lo, hi] (integer system ids in [lo, hi)) or a "
                 f"list of system names, got {_describe(value)}")
        return _BAD

    # --- all ------------------------------------------------------------

    def run(self):
        self.check_root()
        outdir = self.output()
        analysis = self.analysis()
        if "knots" in self.data:
            knots = self.knots()
            if self.problems:
                raise ConfigError(self.problems, self.path)
            return RunConfig(path=self.path, outdir=outdir, bands={}, arcs={}, knots=knots,
                             **analysis)
        bands = self.bands()
        arcs = self.arcs()
        catalogs, catalog_ids = self.catalogs()
        method, pairs_file = self.pairing(catalog_ids)
        parametric = self.parametric()
        if self.problems:
            raise ConfigError(self.problems, self.path)
        return RunConfig(path=self.path, outdir=outdir, bands=bands, arcs=arcs,
                         catalogs=catalogs, pairing_method=method, pairs_file=pairs_file,
                         parametric=parametric, **analysis)


def load_config(path, *, outdir=None):
    """Read and validate a ``lensdual run`` configuration file.

    Every table, key and value is checked, and so are the files they name:
    FITS images, error / weight maps and PSFs are opened (headers only,
    except the small PSF images) to check the HDUs, shapes, WCS and units;
    the ECSV catalogues and pairs file are read to check their columns. The
    schema is described in :mod:`lensdual.config`.

    Parameters
    ----------
    path : path-like
        The TOML configuration file.
    outdir : path-like, optional
        The output directory, replacing ``[output] outdir``; a relative path
        is relative to the current directory (``[output] outdir`` is
        relative to the directory of the configuration file).

    Returns
    -------
    `RunConfig`
        The configuration, with absolute paths and defaults filled in.

    Raises
    ------
    ConfigError
        The file is missing or not valid TOML, or the configuration has
        problems; all of them are listed in the one error.
    """
    cfg_path = Path(path).expanduser().resolve()
    if not cfg_path.exists():
        raise ConfigError([f"configuration file not found: {cfg_path}"], cfg_path)
    if not cfg_path.is_file():
        raise ConfigError([f"not a file: {cfg_path}"], cfg_path)
    try:
        with open(cfg_path, "rb") as fh:
            data = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError([f"invalid TOML: {exc}"], cfg_path) from None
    except UnicodeDecodeError as exc:
        raise ConfigError([f"the file is not UTF-8 text ({exc})"], cfg_path) from None
    except OSError as exc:
        raise ConfigError([f"cannot read the file ({exc})"], cfg_path) from None
    return _Validator(data, cfg_path, outdir).run()


# ---------------------------------------------------------------------------
# reading the images
# ---------------------------------------------------------------------------

_STRUCTURAL = re.compile(
    r"^(SIMPLE|XTENSION|BITPIX|NAXIS\d*|EXTEND|PCOUNT|GCOUNT|BZERO|BSCALE|BLANK|BUNIT|"
    r"CHECKSUM|DATASUM|WCSAXES|(CTYPE|CRPIX|CRVAL|CDELT|CUNIT|CROTA)\d+|(CD|PC|PV|PS)\d+_\d+|"
    r"(A|B|AP|BP)_(ORDER|DMAX|\d+_\d+)|LONPOLE|LATPOLE)$"
)


def _meta(header):
    """The header without the keywords of the data layout, unit and WCS transformation.

    Those are in the CCDData's attributes; kept in ``meta`` they would go stale
    with a cutout (``CRPIX``) or clash with the WCS written by `CCDData.write`.
    """
    meta = header.copy()
    for key in list(meta):
        if key and _STRUCTURAL.match(key):
            meta.remove(key, ignore_missing=True, remove_all=True)
    return meta


def _product_map(path):
    """("error", "ERR") or ("weight", "WHT") when ``path`` is a pipeline product with
    such an extension beside a SCI extension; else None."""
    try:
        with fits.open(path) as hdul:
            names = {h.name.upper() for h in hdul}
    except Exception:  # unreadable files are reported by inspect_fits
        return None
    if "SCI" not in names:
        return None
    if "ERR" in names:
        return ("error", "ERR")
    if "WHT" in names:
        return ("weight", "WHT")
    return None


def _pixel_area(header, hdul):
    """PIXAR_SR of a JWST product (the image's header, else the primary's), or None."""
    for h in (header, hdul[0].header):
        value = h.get("PIXAR_SR")
        if isinstance(value, (int, float)) and value > 0:
            return float(value)
    return None


def _exposure_weighted(spec):
    """True when the weight map is a drizzled product's WHT made with exposure-time
    (not inverse-variance) weights: HST's D###WTSC / FINAL_WHT keywords say 'EXP'."""
    if str(spec.weight_hdu).upper() != "WHT":
        return False
    with fits.open(spec.weight) as hdul:
        for h in hdul:
            for key, value in h.header.items():
                if (key.endswith("WTSC") or key in ("FINALWHT", "FINAL_WHT_TYPE")) and \
                        isinstance(value, str) and value.strip().upper() == "EXP":
                    return True
    return False


def _sky_noise(data, err, mask):
    """``(scatter, quoted)``: the robust (3-sigma clipped) scatter of the image's sky
    pixels and the median error the map quotes there (NaN without sky pixels)."""
    from astropy.stats import sigma_clipped_stats

    good = ~mask & np.isfinite(err)
    _, median, std = sigma_clipped_stats(data[good], sigma=3.0, maxiters=5)
    sky = good & (np.abs(data - median) < 3.0 * std)
    return float(std), (float(np.median(err[sky])) if sky.any() else np.nan)


def _sky_scale(data, err, mask, where):
    """The factor that makes ``err`` match the image's own sky noise (with a warning)."""
    from ..exceptions import LensdualWarning

    std, quoted = _sky_noise(data, err, mask)
    factor = std / quoted if np.isfinite(quoted) else 1.0
    warnings.warn(f"{where}: an exposure-time weight (not inverse variance); errors are "
                  f"1/sqrt(WHT) scaled by {factor:.3g} to the sky noise of the image",
                  LensdualWarning, stacklevel=3)
    return factor


def _read_map(path, hdu, slices, unit=None):
    """A map's pixels; with ``unit``, converted from the map's own BUNIT to it."""
    with fits.open(path) as hdul:
        index = _find_hdu(hdul, hdu, path)
        data = np.array(hdul[index].section[slices], dtype=np.float64)
        bunit = hdul[index].header.get("BUNIT")
    if unit is not None and isinstance(bunit, str) and bunit.strip():
        data *= u.Unit(bunit.strip(), parse_strict="raise").to(unit)
    return data


def _check_noise(data, err, mask, where):
    """Warn when the error map disagrees with the image's own sky noise by > _NOISE_FACTOR."""
    from ..exceptions import LensdualWarning

    if np.count_nonzero(~mask & np.isfinite(err)) < 100:
        return
    std, quoted = _sky_noise(data, err, mask)
    if not (np.isfinite(quoted) and std > 0 and quoted > 0):
        return
    ratio = quoted / std
    if not 1.0 / _NOISE_FACTOR <= ratio <= _NOISE_FACTOR:
        warnings.warn(
            f"{where}: the error map quotes a median sky error of {quoted:.3g}, but the sky "
            f"pixels of the image scatter by {std:.3g} (robust, 3-sigma clipped): "
            f"{ratio:.3g} times the measured noise. Fluxes, positions and every SNR inherit "
            "this error: check the error map's units and scaling", LensdualWarning,
            stacklevel=3)


def _read_image(spec, arc, psf):
    """One CCDData; ValueError / OSError on unusable files."""
    with fits.open(spec.image) as hdul:
        index = _find_hdu(hdul, spec.hdu, spec.image)
        hdu = hdul[index]
        header = hdu.header.copy()
        full_wcs = _header_wcs(header, hdul)
        if not full_wcs.has_celestial:
            raise ValueError(f"the header of {spec.image} has no celestial WCS")
        wcs = full_wcs.celestial
        shape = tuple(hdu.shape)
        slices = (slice(None), slice(None))
        if arc.cutout_center is not None:
            try:
                cut = _cutout(shape, wcs, arc.cutout_center, arc.cutout_size)
            except NoOverlapError:
                raise ValueError(f"the cutout of arc {arc.name} does not overlap "
                                 f"{spec.image}") from None
            slices, wcs = cut.slices_original, cut.wcs
        data = np.array(hdu.section[slices], dtype=np.float64)
        pixar = _pixel_area(header, hdul)
    unit = spec.unit
    if unit is None:
        bunit = header.get("BUNIT")
        bunit = bunit.strip() if isinstance(bunit, str) else ""
        unit = u.Unit(bunit, parse_strict="raise") if bunit else u.dimensionless_unscaled
    map_unit = unit
    scale = 1.0
    if pixar is not None and unit.is_equivalent(u.MJy / u.sr):
        # surface brightness (JWST MJy/sr) to flux per pixel (nJy) with the pixel area
        scale = (unit * u.sr).to(u.nJy) * pixar
        unit = u.nJy
        data *= scale
    mask = ~np.isfinite(data)
    uncertainty = None
    where = f"arc {arc.name}, {spec.image.name}"
    if spec.error is not None:
        err = _read_map(spec.error, spec.error_hdu, slices, unit=map_unit) * scale
        mask |= ~(np.isfinite(err) & (err > 0))
        _check_noise(data, err, mask, f"{where} (error map {spec.error.name})")
        uncertainty = StdDevUncertainty(err)
    elif spec.weight is not None:
        weight = _read_map(spec.weight, spec.weight_hdu, slices) / scale**2
        good = np.isfinite(weight) & (weight > 0)
        err = np.full(weight.shape, np.nan)
        err[good] = 1.0 / np.sqrt(weight[good])
        mask |= ~good
        if _exposure_weighted(spec):  # scaled to the sky noise: nothing left to check
            err *= _sky_scale(data, err, mask, f"{where} (weight map {spec.weight.name})")
        else:
            _check_noise(data, err, mask, f"{where} (weight map {spec.weight.name})")
        uncertainty = StdDevUncertainty(err)
    meta = _meta(header)
    meta["FILENAME"] = str(spec.image)
    return CCDData(data, unit=unit, wcs=wcs, uncertainty=uncertainty, mask=mask,
                   meta=meta, psf=None if psf is None else psf.copy())


def load_images(config):
    """Read the images of both arcs, with their uncertainty, mask, WCS and PSF.

    Parameters
    ----------
    config : `RunConfig`
        A configuration from :func:`load_config`.

    Returns
    -------
    dict
        ``{"L1": {band: CCDData}, "L2": {band: CCDData}}``. Every
        `~astropy.nddata.CCDData` has

        * ``data``: the image (float64), cut out to the arc's cutout
          (`~astropy.nddata.Cutout2D`, ``mode="trim"``) when it has one;
        * ``wcs``: the celestial WCS of the image header (of the cutout);
        * ``unit``: the configured unit, else ``BUNIT``, else dimensionless;
        * ``uncertainty``: a `~astropy.nddata.StdDevUncertainty` from the
          error map, or ``1 / sqrt(weight)`` from the weight map (NaN where
          the weight is not positive), or None;
        * ``mask``: True for NaN / infinite pixels and pixels whose error is
          not finite and positive (or whose weight is not positive);
        * ``psf``: the band's PSF image normalised to unit sum, or None;
        * ``meta``: the image header without its structural and WCS keywords.

    Raises
    ------
    ConfigError
        A file can no longer be read, or a cutout does not overlap its image.
    """
    problems = []
    psfs = {}
    for name, band in config.bands.items():
        if band.psf is not None:
            try:
                psfs[name] = _read_psf(band.psf, band.psf_hdu)
            except (OSError, ValueError) as exc:
                problems.append(f"[{_sec('bands', name)}] psf: {exc}")
    out = {}
    for arc_name, arc in config.arcs.items():
        out[arc_name] = {}
        for band, spec in arc.images.items():
            try:
                out[arc_name][band] = _read_image(spec, arc, psfs.get(band))
            except (OSError, ValueError) as exc:
                problems.append(f"[{_sec('arcs', arc_name, band)}] image: {exc}")
    if problems:
        raise ConfigError(problems, config.path)
    return out


def band_psfs(config):
    """The PSF of every band, as :func:`~lensdual.photometry.psf_photometry` takes it.

    Parameters
    ----------
    config : `RunConfig`
        A configuration from :func:`load_config`.

    Returns
    -------
    dict of str to object
        Per band: the Gaussian FWHM (`~astropy.units.Quantity`), the PSF
        image (2-D float array of odd shape normalised to unit sum), or None
        (the FWHM is to be fitted).

    Raises
    ------
    ConfigError
        A PSF file can no longer be read.
    """
    out, problems = {}, []
    for name, band in config.bands.items():
        if band.psf_fwhm is not None:
            out[name] = band.psf_fwhm
        elif band.psf is not None:
            try:
                out[name] = _read_psf(band.psf, band.psf_hdu)
            except (OSError, ValueError) as exc:
                problems.append(f"[{_sec('bands', name)}] psf: {exc}")
        else:
            out[name] = None
    if problems:
        raise ConfigError(problems, config.path)
    return out


def band_oversampling(config):
    """``{band: oversampling}`` of the bands whose PSF image is oversampled."""
    return {name: band.psf_oversampling for name, band in config.bands.items()
            if band.psf_oversampling is not None}


# ---------------------------------------------------------------------------
# writing TOML
# ---------------------------------------------------------------------------


def _toml_value(value, where):
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        value = float(value)
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return _toml_string(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v, f"{where}[{i}]") for i, v in enumerate(value)) + "]"
    raise TypeError(f"format_config: {where} is a {type(value).__name__}, which cannot be "
                    "written (use str, int, float, bool, lists of those, or dicts)")


def _emit_table(table, path, lines):
    for key in table:
        if not isinstance(key, str):
            where = f" in [{_sec(*path)}]" if path else ""
            raise TypeError(f"format_config: the keys must be strings, got {key!r}{where}")
    values = [(k, v) for k, v in table.items() if not isinstance(v, Mapping)]
    tables = [(k, v) for k, v in table.items() if isinstance(v, Mapping)]
    if path and (values or not tables):
        if lines:
            lines.append("")
        lines.append(f"[{_sec(*path)}]")
    for key, value in values:
        where = ".".join((*path, key))
        lines.append(f"{_toml_key(key)} = {_toml_value(value, where)}")
    for key, sub in tables:
        _emit_table(sub, (*path, key), lines)


def format_config(data, header=None):
    """Write a nested dictionary as TOML text.

    Parameters
    ----------
    data : dict
        String keys; values are str, int, float, bool, lists (or tuples) of
        those, or nested dicts, which become tables (``[a.b.c]``). Keys that
        are not bare TOML keys are quoted.
    header : str, optional
        A comment block to put first (each line prefixed with ``#``).

    Returns
    -------
    str
        The TOML text; ``tomllib.loads(format_config(d)) == d`` for such a
        ``d`` without tuples or NaN.

    Raises
    ------
    TypeError
        A key is not a string or a value has another type.
    """
    if not isinstance(data, Mapping):
        raise TypeError(f"format_config: data must be a dict, got {type(data).__name__}")
    lines = []
    _emit_table(data, (), lines)
    head = []
    if header:
        head = [f"# {line}".rstrip() for line in header.splitlines()]
        if lines:
            head.append("")
    return "\n".join(head + lines) + "\n"


def _umask():
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_config(path, data, header=None):
    """Write a nested dictionary as a TOML file, atomically.

    The text of :func:`format_config` is written to a temporary file in the
    same directory, which then replaces ``path`` (`os.replace`): readers
    never see a partly written file.

    Parameters
    ----------
    path : path-like
        The file to write (replaced if it exists).
    data : dict
        See :func:`format_config`.
    header : str, optional
        A leading comment block.

    Returns
    -------
    `~pathlib.Path`
        ``path``.
    """
    path = Path(path)
    text = format_config(data, header=header)
    mode = path.stat().st_mode & 0o777 if path.exists() else 0o666 & ~_umask()
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path

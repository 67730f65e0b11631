"""Loading and validating a ``lensdual run`` configuration: :func:`load_config` and the
specification classes it returns, :func:`load_images` and :func:`band_psfs`.

The keys, their defaults and bounds come from the schema (`._schema.FIELDS`);
the validator reads each key with the getter of its type and keeps here only
the rules that join several keys.
"""

import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.nddata.utils import NoOverlapError
from astropy.table import Table

from .._pairs_table import repeated_pair_ids
from .._psf_image import check_psf_centred
from ..exceptions import ConfigError, HDUError
from . import _schema
from ._fits import (
    _cutout,
    _grid_mismatch,
    _ImageInfo,
    _inspect_fits,
    _product_map,
    _psf_oversampling,
    _read_image,
    _read_psf,
)
from ._schema import _ARCS, _CUTOUT, _IMAGE_TABLES, MIN_NULL_REALISATIONS
from ._values import _describe, _parse_angle, _parse_center, _parse_unit, _suggest
from ._writer import _sec, _toml_key

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
]

_MIN_PAIRS = 3
#: The keys of every top-level table (none for [bands] and [arcs], whose tables are named
#: by the user), from the schema.
_KEYS = _schema.table_keys()
_BAND_KEYS = _schema.keys("bands.<band>")
_IMAGE_KEYS = _schema.keys("arcs.<arc>.<band>")
_CUTOUT_KEYS = _schema.keys("arcs.<arc>.cutout")

_d = _schema.default  # the default of a key, for the specification classes

_ABSENT = object()  # a key that is not in its table
_BAD = object()  # a value that failed its checks (the problem is recorded)


def _valid(*values):
    """True if none of ``values`` is ``_BAD`` (by identity: values may be Quantities)."""
    return all(v is not _BAD for v in values)


# ---------------------------------------------------------------------------
# the specification classes (ConfigError is in lensdual.exceptions)
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class ImageSpec:
    """One image of an arc in one band, as given in ``[arcs.<arc>.<band>]``.

    Every parameter is also an attribute of the same name.

    Parameters
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
    hdu: int | str | None = _d("arcs.<arc>.<band>", "hdu")
    error: Path | None = _d("arcs.<arc>.<band>", "error")
    error_hdu: int | str | None = _d("arcs.<arc>.<band>", "error_hdu")
    weight: Path | None = _d("arcs.<arc>.<band>", "weight")
    weight_hdu: int | str | None = _d("arcs.<arc>.<band>", "weight_hdu")
    unit: u.UnitBase | None = _d("arcs.<arc>.<band>", "unit")


@dataclass(frozen=True)
class BandSpec:
    """One band, as given in ``[bands.<band>]``.

    Every parameter is also an attribute of the same name.

    Parameters
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
    psf: Path | None = _d("bands.<band>", "psf")
    psf_hdu: int | str | None = _d("bands.<band>", "psf_hdu")
    psf_fwhm: u.Quantity | None = _d("bands.<band>", "psf_fwhm")
    psf_oversampling: int | tuple | None = _d("bands.<band>", "psf_oversampling")


@dataclass(frozen=True)
class ArcSpec:
    """One lens arc: its images and optional cutout (``[arcs.<arc>]``).

    Every parameter is also an attribute of the same name.

    Parameters
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

    Every parameter is also an attribute of the same name.

    Parameters
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
        Positional error of the fit's chi-square (its default, that of
        ``[parametric] sigma_pos``, is coarse on purpose: a smooth parametric
        model is not expected to place images to within the astrometric
        errors).
    centre : `~astropy.coordinates.SkyCoord` or None
        Origin of the fit's frame, e.g. the brightest cluster galaxy; None:
        the Lenstool model's frame when one is given, else the pairs' frame.
    fix_centre : bool
        Hold the centre of the fit's first profile at the origin of its frame
        (``centre``, which is then required), e.g. on the BCG.
    """

    lenstool: Path | None = _d("parametric", "lenstool")
    fit: bool = _d("parametric", "fit")
    model: tuple = _d("parametric", "model")
    z_lens: float | None = _d("parametric", "z_lens")
    z_source: float | None = _d("parametric", "z_source")
    sigma_pos: u.Quantity = _d("parametric", "sigma_pos")
    centre: SkyCoord | None = _d("parametric", "centre")
    fix_centre: bool = _d("parametric", "fix_centre")


@dataclass(frozen=True)
class KnotSpec:
    """A catalogue-only run on a knot constellation (``[knots]``).

    Every parameter is also an attribute of the same name.

    Parameters
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
    centres: dict | None = _d("knots", "centres")
    systems: tuple = _d("knots", "systems")
    assign: str = _d("knots", "assign")
    mapping: Path | None = _d("knots", "mapping")
    models: tuple = _d("knots", "models")
    z_source: float | None = _d("knots", "z_source")
    sigma_pos: u.Quantity | str = _d("knots", "sigma_pos")

    def knot_filter(self):
        """The ``knots`` argument of :func:`~lensdual.pairing.pairs_from_knots`.

        Returns
        -------
        knots : callable, sequence of str or None
            None for every system, a predicate on the system name for a
            range, or the list of the systems named.
        """
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

    Every parameter is also an attribute of the same name.

    Parameters
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
    max_magnification : float
        The automatic pairing's bound on the map (see
        `lensdual.pairing.pair_constellations`).
    estimator : str
        The size-magnification estimator, a key of
        `lensdual.estimators.METHODS`.
    sigma_pos : `~astropy.units.Quantity` or str
        The positional error of the sources (an angle), or ``"auto"`` for
        the errors of the PSF fits.
    n_bootstrap : int
        Number of bootstrap resamplings.
    test : str
        The duality test, one of `lensdual.duality.TESTS`.
    snr_definition : str
        The test's SNR, ``"log"`` or ``"conservative"`` (see
        `lensdual.duality.check_duality`).
    source_model : str
        The sources' model in the PSF photometry, ``"point"`` or ``"resolved"``
        (see `lensdual.photometry.psf_photometry`).
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
    pairing_method: str = _d("pairing", "method")
    pairs_file: Path | None = _d("pairing", "file")
    max_magnification: float = _d("pairing", "max_magnification")
    estimator: str = _d("analysis", "estimator")
    sigma_pos: u.Quantity | str = _d("analysis", "sigma_pos")
    n_bootstrap: int = _d("analysis", "n_bootstrap")
    test: str = _d("analysis", "test")
    snr_definition: str = _d("analysis", "snr_definition")
    source_model: str = _d("analysis", "source_model")
    snr_threshold: float = _d("analysis", "snr_threshold")
    seed: int = _d("analysis", "seed")
    null_realisations: int = _d("analysis", "null_realisations")
    parametric: ParametricSpec | None = None
    knots: KnotSpec | None = None

    def input_files(self):
        """Every file the run reads: the configuration and the files it names.

        Returns
        -------
        list of `~pathlib.Path`
            Absolute paths, each once, the configuration file first.
        """
        files = [self.path]
        for band in self.bands.values():
            files.append(band.psf)
        for arc in self.arcs.values():
            for spec in arc.images.values():
                files += [spec.image, spec.error, spec.weight]
        files += list((self.catalogs or {}).values()) + [self.pairs_file]
        if self.parametric is not None:
            files.append(self.parametric.lenstool)
        if self.knots is not None:
            files += [self.knots.catalogue, self.knots.mapping, *self.knots.models]
        return list(dict.fromkeys(f for f in files if f is not None))




# ---------------------------------------------------------------------------
# validation
# ---------------------------------------------------------------------------


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

    def get(self, table, key, sec, where=None):
        """``table[key]`` read by the getter of its type, with the default and bounds of the
        schema (``where``: the key's table in the schema, e.g. ``"bands.<band>"``; default
        ``sec``)."""
        f = _schema.field(where or sec, key)
        if f.type == "string":
            return self.get_str(table, key, sec, f.default, choices=f.choices)
        if f.type == "integer":
            return self.get_int(table, key, sec, f.default, minimum=f.minimum)
        if f.type == "real":
            return self.get_real(table, key, sec, f.default, above=f.above)
        if f.type == "boolean":
            return self.get_bool(table, key, sec, f.default)
        if f.type == "angle":
            return self.get_angle(table, key, sec, f.default)
        if f.type == "file":
            return self.get_file(table, key, sec)
        if f.type == "HDU":
            return self.get_hdu(table, key, sec)
        raise TypeError(f"{f.name}: no generic getter for a {f.type}")

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
            return _inspect_fits(path, hdu, celestial=celestial)
        except HDUError as exc:
            self.add(f"[{sec}] {hdu_key if exc.on_hdu_key else file_key}: {exc}")
            return None

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
        value = self.get_str(table, "outdir", "output", default=_schema.default("output", "outdir"))
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
        out = {"estimator": self.get(table, "estimator", sec)}
        sigma = table.get("sigma_pos", _schema.default(sec, "sigma_pos"))
        if not isinstance(sigma, str):
            self.add(f'[{sec}] sigma_pos: expected "auto" or an angle string such as '
                     f'"0.01 arcsec", got {_describe(sigma)}')
            sigma = _BAD
        elif sigma != "auto":
            sigma = self.get_angle(table, "sigma_pos", sec, prefix='expected "auto" or an angle; ')
        out["sigma_pos"] = sigma
        for key in ("n_bootstrap", "test", "snr_definition", "source_model", "snr_threshold",
                    "seed"):
            out[key] = self.get(table, key, sec)
        for key, value in (("test", "joint"), ("snr_definition", "conservative")):
            if out[key] == value and out["estimator"] not in ("adaptive", _BAD):
                self.add(f'[{sec}] {key}: "{value}" needs estimator = "adaptive", got '
                         f'estimator = "{out["estimator"]}"')
        null = self.get(table, "null_realisations", sec)
        if null is not _BAD and 0 < null < MIN_NULL_REALISATIONS:
            self.add(f"[{sec}] null_realisations: must be 0 (off) or >= "
                     f"{MIN_NULL_REALISATIONS}, got {null}")
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
            psf, psf_hdu, fwhm = (self.get(spec, key, sec, "bands.<band>")
                                  for key in ("psf", "psf_hdu", "psf_fwhm"))
            if "psf" in spec and "psf_fwhm" in spec:
                self.add(f"[{sec}] psf_fwhm: give either psf (a PSF image) or psf_fwhm "
                         "(a Gaussian FWHM), not both")
            if "psf_hdu" in spec and "psf" not in spec:
                self.add(f"[{sec}] psf_hdu: given without psf")
            image = None
            if psf is not None and psf is not _BAD and psf_hdu is not _BAD:
                if self.inspect_fits(psf, psf_hdu, sec, "psf", "psf_hdu") is not None:
                    try:
                        image = _read_psf(psf, psf_hdu)
                    except Exception as exc:
                        self.add(f"[{sec}] psf: {exc}")
            over = self.oversampling(spec, sec, psf, psf_hdu)
            if image is not None and over is not _BAD:
                try:
                    check_psf_centred(image, over, f"the PSF image in {psf}")
                except ValueError as exc:
                    self.add(f"[{sec}] psf: {exc}")
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
        self.distinct_arcs(arcs)
        return arcs

    def distinct_arcs(self, arcs):
        """The two arcs may not be the same image (file, HDU and cutout) in a band."""
        if len(arcs) < 2 or any(a is None for a in arcs.values()):
            return
        l1, l2 = arcs["L1"], arcs["L2"]
        cuts = (l1.cutout_center, l1.cutout_size, l2.cutout_center, l2.cutout_size)
        if (cuts[0] is None) != (cuts[2] is None) or (cuts[0] is not None
                                                      and not _valid(*cuts)):
            return
        if cuts[0] is not None and not (
                cuts[0].separation(cuts[2]) < 1e-3 * u.arcsec
                and np.array_equal(np.atleast_1d(cuts[1].to_value(u.arcsec)),
                                   np.atleast_1d(cuts[3].to_value(u.arcsec)))):
            return
        for band, spec in l1.images.items():
            other = l2.images.get(band)
            if other is None:
                continue
            if spec.image == other.image and spec.hdu == other.hdu:
                self.add(f"[arcs.L2.{band}] image: the same image as [arcs.L1.{band}] "
                         f"({spec.image}{'' if spec.hdu is None else f', HDU {spec.hdu}'}, "
                         "same cutout): the two arcs must be two different images of the "
                         "source")

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
        for band, info in given[1:]:
            why = _grid_mismatch(ref, info)
            if why is None:
                continue
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

    def image_unit_key(self, table, sec):
        """The ``unit`` of an image table: None (not given), a unit, or _BAD (recorded)."""
        if "unit" not in table:
            return None
        if not isinstance(table["unit"], str):
            self.add(f"[{sec}] unit: expected a unit string such as \"nJy\", "
                     f"got {_describe(table['unit'])}")
            return _BAD
        unit, message = _parse_unit(table["unit"])
        if unit is None:
            self.add(f"[{sec}] unit: {message}")
            return _BAD
        return unit

    def check_bunit(self, info, unit, table, sec, image):
        """The image's BUNIT: a valid unit, and the one of ``unit`` when both are given."""
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

    def check_maps(self, maps, info, image_unit, sec):
        """The error or weight map of an image: its shape, and the error map's unit."""
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

    def image(self, table, sec):
        self.unknown_keys(table, _IMAGE_KEYS, sec)
        if "image" not in table:
            self.add(f"[{sec}] image: missing (the FITS file of the image)")
            image = _BAD
        else:
            image = self.get(table, "image", sec, "arcs.<arc>.<band>")
        hdu = self.get(table, "hdu", sec, "arcs.<arc>.<band>")
        maps = {}
        for key in ("error", "weight"):
            path = self.get(table, key, sec, "arcs.<arc>.<band>")
            map_hdu = self.get(table, f"{key}_hdu", sec, "arcs.<arc>.<band>")
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
        unit = self.image_unit_key(table, sec)
        info = None
        if image is not _BAD and hdu is not _BAD:
            info = self.inspect_fits(image, hdu, sec, "image", "hdu", celestial=True)
            self.check_bunit(info, unit, table, sec, image)
        if unit is _BAD or info is None:
            image_unit = None  # unknown: its problem is already recorded
        elif unit is not None:
            image_unit = unit
        elif info.bunit:
            image_unit = _parse_unit(info.bunit)[0]
        else:
            image_unit = u.dimensionless_unscaled
        self.check_maps(maps, info, image_unit, sec)
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
            path = self.get(table, arc, "catalogs")
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
        method = self.get(table, "method", sec)
        path = self.get(table, "file", sec)
        if method == "manual" and "file" not in table:
            self.add('[pairing] file: required when method = "manual" (an ECSV table with '
                     "integer columns id1, id2)")
        if method == "auto" and "file" in table:
            self.add('[pairing] file: a pairs file is only used with method = "manual" '
                     '(set method = "manual", or remove file)')
        if path is not None and path is not _BAD:
            self.pairs(path, catalog_ids)
        return method, path, self.get(table, "max_magnification", sec)

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
        if "pair_id" in tab.colnames:
            repeated, rows = repeated_pair_ids(tab["pair_id"])
            if repeated:
                self.add(f"{loc}: pair_id value(s) {repeated} of {path} occur more than once "
                         f"(rows {rows}); each pair needs its own pair_id")
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
        lenstool, fit = self.get(table, "lenstool", sec), self.get(table, "fit", sec)
        model = self.model(table.get("model", _ABSENT))
        z_lens, z_source = self.get(table, "z_lens", sec), self.get(table, "z_source", sec)
        if fit is True or "lenstool" in table:
            why = "fit = true" if fit is True else "lenstool is given"
            for key, value in (("z_lens", z_lens), ("z_source", z_source)):
                if value is None:
                    self.add(f"[parametric] {key}: required when {why}")
        if isinstance(z_lens, float) and isinstance(z_source, float) and z_source <= z_lens:
            self.add(f"[parametric] z_source: must be larger than z_lens ({z_lens:g}), "
                     f"got {z_source:g}")
        sigma_pos = self.get(table, "sigma_pos", sec)
        centre = None
        if "centre" in table:
            centre, message = _parse_center(table["centre"])
            if centre is None:
                self.add(f"[parametric] centre: {message}")
        fix_centre = self.get(table, "fix_centre", sec)
        if fix_centre is True and "centre" not in table:
            self.add("[parametric] fix_centre: needs centre (the sky position to hold the "
                     "first profile's centre at)")
        return ParametricSpec(lenstool=lenstool, fit=fit, model=model, z_lens=z_lens,
                              z_source=z_source, sigma_pos=sigma_pos, centre=centre,
                              fix_centre=fix_centre)

    def model(self, value):
        if value is _ABSENT:
            return _schema.default("parametric", "model")
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
        catalogue = self.get(table, "catalogue", sec)
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
        centres = self.knot_centres(table.get("centres", _ABSENT), names)
        systems = self.knot_systems(table.get("systems", _ABSENT))
        mapping = self.get(table, "mapping", sec)
        models = self.knot_models(table.get("models", _ABSENT))
        f = _schema.field(sec, "assign")
        default = "mapping" if "mapping" in table else "model" if models else f.default
        assign = self.get_str(table, "assign", sec, default, choices=f.choices)
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
        z_source = self.get(table, "z_source", sec)
        sigma = table.get("sigma_pos", _schema.default(sec, "sigma_pos"))
        if sigma != "auto":
            sigma = self.get_angle(table, "sigma_pos", sec,
                                   prefix='expected "auto" or an angle; ')
        if not _valid(catalogue, names, centres, systems, mapping, models, assign, z_source,
                      sigma):
            return _BAD
        return KnotSpec(catalogue=catalogue, macro_images=tuple(names), centres=centres,
                        systems=systems, assign=assign, mapping=mapping, models=models,
                        z_source=z_source, sigma_pos=sigma)

    def knot_models(self, models):
        if models is _ABSENT:
            return _schema.default("knots", "models")
        if isinstance(models, str):
            models = [models]
        if not isinstance(models, list) or not all(isinstance(m, str) for m in models):
            self.add(f"[knots] models: expected a list of Lenstool files, got {_describe(models)}")
            return _BAD
        models = tuple(self.get_file({"models": m}, "models", "knots") for m in models)
        return models if _valid(*models) else _BAD

    def knot_centres(self, value, names):
        if value is _ABSENT or value == "catalogue":
            return _schema.default("knots", "centres")
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
            return _schema.default("knots", "systems")
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

    def inputs_outside(self, config):
        """The output directory must hold none of the files the run reads."""
        if config.outdir is None:
            return
        where = "outdir (argument)" if self.outdir_arg is not None else "[output] outdir"
        inside = [f for f in config.input_files() if f.is_relative_to(config.outdir)]
        if inside:
            names = ", ".join(str(f.relative_to(config.outdir)) for f in inside[:4])
            more = f" and {len(inside) - 4} more" if len(inside) > 4 else ""
            self.add(f"{where}: the output directory {config.outdir} holds {names}{more}, "
                     "read by this run; a run never replaces or removes its own inputs, so "
                     "choose an output directory that holds none of them")

    def run(self):
        self.check_root()
        outdir = self.output()
        analysis = self.analysis()
        if "knots" in self.data:
            knots = self.knots()
            if self.problems:
                raise ConfigError(self.problems, self.path)
            config = RunConfig(path=self.path, outdir=outdir, bands={}, arcs={}, knots=knots,
                               **analysis)
        else:
            bands = self.bands()
            arcs = self.arcs()
            catalogs, catalog_ids = self.catalogs()
            method, pairs_file, max_magnification = self.pairing(catalog_ids)
            parametric = self.parametric()
            if self.problems:
                raise ConfigError(self.problems, self.path)
            config = RunConfig(path=self.path, outdir=outdir, bands=bands, arcs=arcs,
                               catalogs=catalogs, pairing_method=method,
                               pairs_file=pairs_file, max_magnification=max_magnification,
                               parametric=parametric, **analysis)
        self.inputs_outside(config)
        if self.problems:
            raise ConfigError(self.problems, self.path)
        return config


def _toml_hint(text, exc):
    """What a TOML error means where the parser's words do not say it (a repeated key)."""
    found = re.search(r"at line (\d+)", str(exc))
    if "Cannot overwrite a value" not in str(exc) or not found:
        return ""
    lineno = int(found.group(1))
    lines = text.splitlines()
    if lineno > len(lines):
        return ""
    key = lines[lineno - 1].split("=", 1)[0].strip()
    return f": the key {key!r} is given twice in its table" if key else ""


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
    cfg_path, data = read_toml(path)
    return _Validator(data, cfg_path, outdir).run()


def read_toml(path):
    """``(absolute path, parsed document)`` of a TOML configuration file.

    Raises `ConfigError` (naming the file) where it is missing, not a file,
    unreadable, not UTF-8 or not valid TOML.
    """
    cfg_path = Path(path).expanduser().resolve()
    if not cfg_path.exists():
        raise ConfigError([f"configuration file not found: {cfg_path}"], cfg_path)
    if not cfg_path.is_file():
        raise ConfigError([f"not a file: {cfg_path}"], cfg_path)
    try:
        # utf-8-sig: a byte-order mark (as some Windows editors write) is not TOML
        text = cfg_path.read_bytes().decode("utf-8-sig")
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError([f"invalid TOML: {exc}{_toml_hint(text, exc)}"], cfg_path) from None
    except UnicodeDecodeError as exc:
        raise ConfigError([f"the file is not UTF-8 text ({exc})"], cfg_path) from None
    except OSError as exc:
        raise ConfigError([f"cannot read the file ({exc})"], cfg_path) from None
    return cfg_path, data


# ---------------------------------------------------------------------------
# reading the images
# ---------------------------------------------------------------------------


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
    """``{band: oversampling}`` of the bands whose PSF image is oversampled.

    Parameters
    ----------
    config : `RunConfig`
        A configuration from :func:`load_config`.

    Returns
    -------
    oversampling : dict of str to int
        The ``psf_oversampling`` of every band that has one.
    """
    return {name: band.psf_oversampling for name, band in config.bands.items()
            if band.psf_oversampling is not None}

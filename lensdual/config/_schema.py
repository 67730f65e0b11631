"""The schema of a ``lensdual run`` configuration: every table and key, declared once.

`FIELDS` is the one declarative table of the TOML keys: for each, its table,
type, default, bounds or choices and a one-line description. Everything else
derives from it: the keys the validator accepts (`table_keys`), the defaults
and bounds of the typed getters (:class:`lensdual.config._core._Validator`),
the defaults of `~lensdual.config.RunConfig` and of the other specification
classes (`default`), and the table of keys in the documentation
(`schema_table`).

Where a default is also the library's (the estimator), it is imported from
the library rather than repeated.
"""

import tomllib
from dataclasses import dataclass

from astropy import units as u

from ..duality import (
    DEFAULT_SNR_DEFINITION,
    DEFAULT_SNR_THRESHOLD,
    DEFAULT_TEST,
    LOG_SNR_DEFINITIONS,
    TESTS,
)
from ..estimators import DEFAULT_METHOD, DEFAULT_N_BOOTSTRAP, METHODS
from ..inference import ANOMALIES, MIN_REALISATIONS, MODELS
from ..pairing import DEFAULT_MAX_MAGNIFICATION
from ..parametric.fitting import DEFAULT_MODEL
from ..pipeline import DEFAULT_SEED
from ..simulation.families import FAMILIES
from ._writer import _toml_string, _toml_value

__all__ = ["Field", "FIELDS", "TABLES", "REQUIRED", "MIN_NULL_REALISATIONS", "table_keys",
           "field", "default", "keys", "example", "schema_table", "INFERENCE_FIELDS",
           "INFERENCE_TABLES", "INFERENCE_OUTDIR", "INFERENCE_SYSTEM", "inference_field"]

#: The arcs of a run, in order.
_ARCS = ("L1", "L2")
#: The table of an arc holding its cutout (so no band may be called this).
_CUTOUT = "cutout"
#: The fewest realisations of the null calibration (else 0: off).
MIN_NULL_REALISATIONS = 100


class _Required:
    """The default of a key that must be given whenever its table is."""

    def __repr__(self):
        return "REQUIRED"


#: The `Field.default` of a key that must be given whenever its table is.
REQUIRED = _Required()


@dataclass(frozen=True)
class Field:
    """One key of the configuration file.

    Parameters
    ----------
    table : str
        The TOML table holding the key, e.g. ``"analysis"``; tables named
        by the user are written ``"bands.<band>"``, ``"arcs.<arc>.<band>"``
        and ``"arcs.<arc>.cutout"``.
    key : str
        The key.
    type : str
        What the value is, in words (``"integer"``, ``"angle"``, ``"file"``...);
        the validator reads ``"string"``, ``"integer"``, ``"real"``,
        ``"boolean"``, ``"angle"``, ``"file"`` and ``"HDU"`` values with its
        generic getters, the others with rules of their own.
    default : object
        The value a loaded configuration holds when the key is left out
        (e.g. None, or an `~astropy.units.Quantity` for an angle), or
        `REQUIRED`.
    doc : str
        One line: what the key means.
    minimum : int, optional
        Integers only: the smallest value accepted (``value >= minimum``).
    above : float, optional
        Reals only: the value must be larger (``value > above``).
    choices : tuple of str, optional
        Strings only: the values accepted.
    shown : str, optional
        The default as the documentation shows it, when it is not the TOML
        spelling of ``default`` (e.g. a default that depends on other keys).
    note : str, optional
        The comment of the key in the annotated example of the
        documentation, when the type and bounds do not say it.
    attr : str, optional
        The attribute of the loaded specification that holds the value
        (`~lensdual.config.RunConfig`, `~lensdual.config.BandSpec`...);
        default ``key``.
    """

    table: str
    key: str
    type: str
    default: object = None
    doc: str = ""
    minimum: int | None = None
    above: float | None = None
    choices: tuple | None = None
    shown: str | None = None
    note: str | None = None
    attr: str | None = None

    @property
    def name(self):
        """``"[table] key"``, as the error messages and the documentation name the key."""
        return f"[{self.table}] {self.key}"

    @property
    def top(self):
        """The top-level table of the key (``"bands"`` for ``"bands.<band>"``)."""
        return self.table.split(".", 1)[0]

    @property
    def attribute(self):
        """The attribute of the loaded specification that holds the value."""
        return self.attr or self.key

    @property
    def required(self):
        """Whether the key must be given whenever its table is."""
        return self.default is REQUIRED

    def bounds(self):
        """The bounds or choices of the value in words.

        Returns
        -------
        str
            E.g. ``">= 10"``, ``"> 0"``, ``'"auto", "manual"'``, or ``""``.
        """
        if self.minimum is not None:
            return f">= {self.minimum}"
        if self.above is not None:
            return f"> {self.above:g}"
        if self.choices is not None:
            return ", ".join(_toml_string(c) for c in self.choices)
        return ""

    def shown_default(self):
        """The default as the documentation shows it.

        Returns
        -------
        str
            The default in TOML spelling (e.g. ``"auto"``, ``1000``), or in
            words (``required``, ``none``, or how it depends on other keys).
        """
        if self.shown is not None:
            return self.shown
        value = self.default
        if value is REQUIRED:
            return "required"
        if value is None:
            return "none"
        if isinstance(value, u.Quantity):
            return _toml_string(f"{value.value:g} {value.unit}")
        return _toml_value(value, self.name)

    def example_line(self):
        """The key's line in the annotated example of the documentation.

        Returns
        -------
        str
            ``key = default`` and a comment: the `note`, else the type and
            bounds or choices, e.g. ``n_bootstrap = 1000  # integer >= 10``.
        """
        if self.note is not None:
            comment = self.note.format(default=self.shown_default())
        elif self.choices is not None:
            rest = [_toml_string(c) for c in self.choices if c != self.default]
            comment = (f"{self.shown_default()} (default), {', '.join(rest[:-1])} or "
                       f"{rest[-1]}")
        else:
            comment = f"{self.type} {self.bounds()}".strip()
        return f"{self.key} = {self.shown_default()}".ljust(33) + f"# {comment}"

    def shown_is_toml(self):
        """Whether `shown_default` is a TOML value.

        Returns
        -------
        bool
            True for a TOML value, False for words.
        """
        if self.shown is not None:
            try:
                tomllib.loads(f"value = {self.shown}")
            except tomllib.TOMLDecodeError:
                return False
            return True
        return self.default is not REQUIRED and self.default is not None


_F = Field

#: Every key of a configuration file, table by table, in the order of the documentation.
FIELDS = (
    _F("output", "outdir", "directory", "lensdual-output",
       "the output directory (relative to the configuration file's directory); it may "
       "hold none of the files the run reads",
       note="optional; default {default}"),

    _F("analysis", "estimator", "string", DEFAULT_METHOD,
       "the size-magnification estimator (lensdual.estimators.METHODS)",
       choices=tuple(METHODS)),
    _F("analysis", "sigma_pos", '"auto" or angle', "auto",
       'positional error of the sources: "auto" (errors of the PSF fits) or an angle > 0',
       note='"auto" (errors of the PSF fits) or an angle > 0'),
    _F("analysis", "n_bootstrap", "integer", DEFAULT_N_BOOTSTRAP, "number of bootstrap resamplings",
       minimum=10),
    _F("analysis", "test", "string", DEFAULT_TEST,
       'the duality test: "geometric" (the flux ratio against mu_size), "joint" (against '
       "mu_size and the neighbours' flux ratios; needs estimator \"adaptive\" and two bands) "
       'or "auto" (joint where it applies, else geometric)',
       choices=("auto",) + tuple(TESTS)),
    _F("analysis", "snr_definition", "string", DEFAULT_SNR_DEFINITION,
       'the SNR of the test: "log" (linearised in ln mu_size), "conservative" (the smaller of '
       "that and the profile-likelihood SNR, a flag needs both; needs estimator "
       '"adaptive") or "auto" (conservative with the adaptive estimator, else log)',
       choices=("auto",) + LOG_SNR_DEFINITIONS),
    _F("analysis", "source_model", "string", "point",
       'the sources\' model in the PSF photometry: "point" (the PSF) or "resolved" (the PSF '
       "convolved with an elliptical Gaussian of free size, for star clusters the lens "
       "stretches beyond the PSF; noisier on point sources)",
       choices=("point", "resolved")),
    _F("analysis", "snr_threshold", "real", DEFAULT_SNR_THRESHOLD,
       "significance threshold of a duality violation", above=0),
    _F("analysis", "seed", "integer", DEFAULT_SEED, "seed of the random numbers", minimum=0),
    _F("analysis", "null_realisations", "integer", 0,
       f"realisations of the null calibration: 0 (off) or >= {MIN_NULL_REALISATIONS} "
       "(>= 370 for its empirical p-values to confirm a flag at SNR 3); "
       'needs estimator "adaptive"',
       minimum=0, note=f"0 (off) or >= {MIN_NULL_REALISATIONS}: null calibration "
                       '(estimator "adaptive")'),

    _F("bands.<band>", "psf", "file", None,
       "a PSF image (FITS, odd shape, the pixel scale of the images)"),
    _F("bands.<band>", "psf_hdu", "HDU", None,
       "the HDU of the PSF image (index or EXTNAME); needs psf", shown="the first 2-D image"),
    _F("bands.<band>", "psf_fwhm", "angle", None,
       "the FWHM of a Gaussian PSF (not with psf); neither: the FWHM is fitted",
       shown="none (fitted)"),
    _F("bands.<band>", "psf_oversampling", "integer or [oy, ox]", None,
       "the oversampling of the PSF image (>= 1); needs psf",
       shown="the file's OVERSAMP, else 1"),

    _F("arcs.<arc>.<band>", "image", "file", REQUIRED,
       "the image (FITS with a celestial WCS); arcs L1 and L2 each need every band"),
    _F("arcs.<arc>.<band>", "hdu", "HDU", None, "the HDU of the image (index or EXTNAME)",
       shown="the first 2-D image"),
    _F("arcs.<arc>.<band>", "error", "file", None,
       "a 1-sigma error map of the image's shape (not with weight)",
       shown="none (a pipeline product's ERR)"),
    _F("arcs.<arc>.<band>", "error_hdu", "HDU", None,
       "the HDU of the error map; without error: of the image's file",
       shown="the first 2-D image"),
    _F("arcs.<arc>.<band>", "weight", "file", None,
       "an inverse-variance weight map of the image's shape (not with error)",
       shown="none (a pipeline product's WHT)"),
    _F("arcs.<arc>.<band>", "weight_hdu", "HDU", None,
       "the HDU of the weight map; without weight: of the image's file",
       shown="the first 2-D image"),
    _F("arcs.<arc>.<band>", "unit", "unit", None,
       "the unit of the image and its error map (an astropy unit)",
       shown="BUNIT, else dimensionless"),

    _F("arcs.<arc>.cutout", "center", "sky position", REQUIRED,
       'the centre of the cutout (ICRS "RA Dec"; plain numbers are degrees)',
       attr="cutout_center"),
    _F("arcs.<arc>.cutout", "size", "angle or [ny, nx]", REQUIRED,
       "the size of the cutout: one angle (a square) or two", attr="cutout_size"),

    _F("catalogs", "L1", "file", None,
       "the sources of arc L1 (ECSV: integer 'id', SkyCoord 'sky' or 'ra', 'dec' in deg); "
       "both arcs or neither"),
    _F("catalogs", "L2", "file", None, "the sources of arc L2, as L1"),

    _F("pairing", "method", "string", "auto", "how the sources of the arcs are paired",
       choices=("auto", "manual"), attr="pairing_method"),
    _F("pairing", "file", "file", None,
       'the pairs (ECSV: integer columns id1, id2); method = "manual" only, and required',
       attr="pairs_file"),
    _F("pairing", "max_magnification", "real", DEFAULT_MAX_MAGNIFICATION,
       "the automatic search's bound on the map: |det A| within [1/b, b], stretch below b",
       above=1),

    _F("parametric", "lenstool", "file", None, "a Lenstool parameter file to compare with"),
    _F("parametric", "fit", "boolean", False, "fit a lenstronomy model to the pairs"),
    _F("parametric", "model", "list of strings", DEFAULT_MODEL,
       "the lenstronomy profiles of the fit"),
    _F("parametric", "z_lens", "real", None,
       "the lens redshift; required with fit = true or lenstool", above=0),
    _F("parametric", "z_source", "real", None,
       "the source redshift, > z_lens; required with fit = true or lenstool", above=0),
    _F("parametric", "sigma_pos", "angle", 0.01 * u.arcsec,
       "the positional error of the fit's chi-square"),
    _F("parametric", "centre", "sky position", None,
       "the origin of the fit's frame (e.g. the BCG)",
       shown="the Lenstool model's frame, else the pairs'"),
    _F("parametric", "fix_centre", "boolean", False,
       "hold the first profile's centre at centre (which it needs)"),

    _F("knots", "catalogue", "file", REQUIRED,
       "a multiple-image catalogue: Lenstool, or ECSV with 'id' and 'sky' (or 'ra', 'dec')"),
    _F("knots", "macro_images", "list of strings", REQUIRED,
       "the names of the macro-images, at least 2"),
    _F("knots", "centres", '"catalogue" or table', None,
       'the macro-images\' centres: read from the catalogue\'s comments, or {name = "RA Dec"}',
       shown='"catalogue"'),
    _F("knots", "systems", "[lo, hi] or list of names", (),
       "the knot systems: integer ids in [lo, hi), or names", shown="all"),
    _F("knots", "assign", "string", "centre", "how knots are assigned to macro-images",
       choices=("centre", "mapping", "model"),
       shown='"mapping" with mapping, "model" with models, else "centre"'),
    _F("knots", "mapping", "file", None, "ECSV with columns id, macro (assign = \"mapping\")"),
    _F("knots", "models", "list of files", (),
       "Lenstool models to compare with (the first assigns with assign = \"model\")",
       shown="[]"),
    _F("knots", "z_source", "real", None, "the redshift of the knots", above=0,
       shown="the catalogue's"),
    _F("knots", "sigma_pos", '"auto" or angle', "auto",
       'the position error: "auto" (per pair of macro-images, from the residuals) or an angle'),
)

#: The default output directory of ``lensdual infer`` (its ``[output] outdir``).
INFERENCE_OUTDIR = "lensdual-inference"
#: The schema's name of the tables of the ``[[inference.system]]`` array.
INFERENCE_SYSTEM = "inference.system"

#: The keys of a ``lensdual infer`` configuration: ``[output]`` (as `FIELDS`, with
#: the default `INFERENCE_OUTDIR`), ``[inference]`` and every table of the
#: ``[[inference.system]]`` array.
INFERENCE_FIELDS = (
    _F("inference", "model", "string", "CDM",
       'the dark-matter model of the sub-haloes (lensdual.inference.MODELS)',
       choices=tuple(MODELS)),
    _F("inference", "log_mhm", "real or [real, ...]", None,
       'log10 of the WDM half-mode mass [Msun]; required with model = "WDM", not with "CDM"; '
       "a list of at least two (e.g. [5, 6, 7, 8, 9, 10]) runs the joint posterior on "
       "sigma_sub and the half-mode mass"),
    _F("inference", "log_m_host", "real", 15.0,
       "log10 of the host halo's mass [Msun] (pyHalo's host scaling of sigma_sub)"),
    _F("inference", "los_normalization", "real", 0.0,
       "line-of-sight haloes at this multiple of pyHalo's field-halo mass function "
       "(pyHalo's LOS_normalization; 0: none, 1: pyHalo's default), in the model's every "
       "realisation whatever sigma_sub", note=">= 0: 0 (none) or pyHalo's 1"),
    _F("inference", "two_halo", "boolean", True,
       "with line-of-sight haloes, pyHalo's two-halo term (correlated structure around the "
       "host, in the lens plane)"),
    _F("inference", "sigma_sub", "[min, max]", (1e-3, 0.3),
       "the bounds of the abundance grid and of its log-uniform prior, kpc^-2 "
       "(0 < min < max)", shown="[0.001, 0.3]", note="kpc^-2: the prior's bounds"),
    _F("inference", "n_sigma_sub", "integer", 30,
       'abundances of the grid, log-spaced (>= 5 with weight = "composite")', minimum=2),
    _F("inference", "n_realisations", "integer", 1000,
       "realisations of the population per abundance and image", minimum=MIN_REALISATIONS),
    _F("inference", "seed", "integer", 0, "seed of the realisations and the mocks", minimum=0),
    _F("inference", "calibrate", "boolean", True,
       "recalibrate the posterior on n_calibration mock universes of each system, made as "
       "the data (lensdual.inference.calibrate_posterior), so that its intervals hold the "
       "truth as often as they say (with a list of log_mhm, both marginals)"),
    _F("inference", "n_calibration", "integer", 300,
       "mock universes of each system's calibration (calibrate = true); combined systems "
       "share their truths", minimum=50),
    _F("inference", "weight", '"composite" or real', None,
       'each system\'s composite-likelihood weight: "composite" (measured on mocks of the '
       "constellation, lensdual.inference.composite_weight) or a number in (0, 1] "
       "(1: the pairs' errors independent); a calibrated posterior's mocks take the same "
       "weight",
       shown='1 with calibrate, else "composite"',
       note='"composite" (by simulation) or a number in (0, 1]'),
    _F("inference", "n_mocks", "integer", 100,
       'mock universes of each composite weight (weight = "composite")', minimum=20),
    _F("inference", "anomaly", "string", "auto",
       'the pairs\' anomalies: "geometric" (the flux ratio against mu_size, in every duality '
       'table), "joint" (against the joint test\'s prediction, which also reads the '
       'neighbours\' flux ratios; every table a joint-test table) or "auto" (joint where '
       "every system's table is a joint-test table, else geometric)",
       choices=("auto", *ANOMALIES)),

    _F(INFERENCE_SYSTEM, "name", "string", None,
       "the system's name in the report and the posterior's metadata",
       shown="the pairs file's stem (its folder's name for pairs.ecsv)"),
    _F(INFERENCE_SYSTEM, "pairs", "file", REQUIRED,
       "the analysed constellation: the pairs.ecsv of lensdual run (or any check_duality "
       "result written as ECSV)"),
    _F(INFERENCE_SYSTEM, "lenstool", "file", None,
       "the smooth lens: a Lenstool parameter file (best.par); the pairs are placed in its "
       "frame by their sky1, sky2 columns (else x, y about meta['reference']); not with "
       "family"),
    _F(INFERENCE_SYSTEM, "family", "string", None,
       "the smooth lens of a mock: a lens family of lensdual.simulation.FAMILIES, the pairs "
       "in its frame; not with lenstool", choices=tuple(FAMILIES)),
    _F(INFERENCE_SYSTEM, "z_source", "real", None,
       "the source redshift, > the model's z_lens; required with lenstool (a family has "
       "its own)", above=0),
    _F(INFERENCE_SYSTEM, "sigma_pos", "angle", None,
       "the position error of the mocks (calibration, composite weight)",
       shown="the table's (its duality test's, else the median pos_err)"),
    _F(INFERENCE_SYSTEM, "flux_rel_err", "real", None,
       "the relative flux error of the mocks (calibration, composite weight)", above=0,
       shown="the table's median flux_err / flux"),
    _F(INFERENCE_SYSTEM, "radius", "angle", None,
       "the radius of the disc of sub-haloes around every image",
       shown="per arc, the median nearest-neighbour separation"),
)

del _F

#: The top-level tables of a ``lensdual infer`` configuration.
INFERENCE_TABLES = ("output", "inference")

_BY_NAME_INFERENCE = {(f.table, f.key): f for f in INFERENCE_FIELDS}


def inference_field(table, key):
    """The `Field` of ``key`` in ``table`` of a ``lensdual infer`` configuration
    (``"output"``, ``"inference"`` or `INFERENCE_SYSTEM`)."""
    if table == "output":
        return _BY_NAME[(table, key)]
    return _BY_NAME_INFERENCE[(table, key)]


#: The top-level tables, in order.
TABLES = ("output", "analysis", "bands", "arcs", "catalogs", "pairing", "parametric", "knots")

#: Tables a catalogue-only ([knots]) run does without.
_IMAGE_TABLES = ("bands", "arcs", "catalogs", "pairing", "parametric")

_BY_NAME = {(f.table, f.key): f for f in FIELDS}


def field(table, key):
    """The `Field` of ``key`` in ``table`` (e.g. ``field("analysis", "seed")``)."""
    return _BY_NAME[(table, key)]


def default(table, key):
    """The default of ``key`` in ``table``: the value a loaded configuration holds."""
    return _BY_NAME[(table, key)].default


def keys(table):
    """The keys of ``table`` (e.g. ``"bands.<band>"``), in order."""
    return tuple(f.key for f in FIELDS if f.table == table)


def table_keys():
    """``{top-level table: its keys}``; the tables of user-named tables (``[bands]``,
    ``[arcs]``) hold no keys of their own."""
    return {t: keys(t) for t in TABLES}


def example(table):
    """The lines of ``table``'s keys in the annotated example, each with its default.

    Parameters
    ----------
    table : str
        A table of the schema, e.g. ``"analysis"``.

    Returns
    -------
    str
        One `Field.example_line` per key, indented by four spaces.
    """
    return "\n".join(f"    {f.example_line()}" for f in FIELDS if f.table == table)


def _cell(text):
    """``text`` as a cell of an rst list-table (one line)."""
    return text.replace("*", r"\*").replace("|", r"\|")


def schema_table(fields=None):
    """The keys of the configuration as a reStructuredText table, from `FIELDS`.

    Parameters
    ----------
    fields : sequence of `Field`, optional
        The keys of the table; default `FIELDS` (``lensdual run``), e.g.
        `INFERENCE_FIELDS` for ``lensdual infer``.

    Returns
    -------
    str
        A ``list-table`` with one row per key: the table and key, its type
        and bounds, its default (in TOML spelling) and what it means.
    """
    lines = [".. list-table::", "   :header-rows: 1", "   :widths: 28 20 20 32", "",
             "   * - Key", "     - Type", "     - Default", "     - Meaning"]
    for f in FIELDS if fields is None else fields:
        bounds = f.bounds()
        kind = f"{f.type} {bounds}" if f.minimum is not None or f.above is not None else f.type
        meaning = f"{f.doc}; one of {bounds}" if f.choices else f.doc
        shown = f"``{f.shown_default()}``" if f.shown_is_toml() else _cell(f.shown_default())
        lines += [f"   * - ``{f.name}``", f"     - {_cell(kind)}", f"     - {shown}",
                  f"     - {_cell(meaning)}"]
    return "\n".join(lines) + "\n"

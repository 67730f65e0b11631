r"""Configuration files of ``lensdual run``: schema, validation and loading.

A run is described by a TOML file. :func:`load_config` reads it, checks every
table, key, value and referenced file (FITS headers and HDUs, ECSV columns)
and returns a :class:`RunConfig`; all the problems it finds are reported
together in one :class:`ConfigError`. :func:`load_images` then reads the
images as `~astropy.nddata.CCDData` (with WCS, uncertainty, mask and PSF) and
:func:`band_psfs` gives the PSF of every band in the form
:func:`~lensdual.photometry.psf_photometry` accepts. :func:`format_config` and
:func:`write_config` write a nested dictionary as TOML text.

Every key is declared once, in ``FIELDS`` (a tuple of :class:`Field`: table,
key, type, default, bounds or choices, meaning): the validator, the defaults
of :class:`RunConfig` and the table of keys below (:func:`schema_table`) are
made from it.

.. rubric:: The schema

Every table and key below is shown; tables and keys marked optional may be
left out. Relative paths are relative to the directory of the configuration
file. Angles are strings of a number and an angular unit (``"0.066 arcsec"``,
``"10 mas"``, ``"1.2e-5 deg"``). ::

    [output]
@output@

    [analysis]                       # optional, as is every key in it
@analysis@

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
    max_magnification = 20.0         # optional (auto): the map's |det A| within
                                     # [1/b, b] and stretch below b (default 20)

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

.. rubric:: Every key

Made from ``FIELDS`` by :func:`schema_table`. A default in TOML spelling is
what a left-out key means; ``required`` keys must be given whenever their
table is.

"""

from . import _schema
from ._core import *  # noqa: F403
from ._core import __all__ as _core_all
from ._infer import InferenceConfig, InferenceSystemSpec, load_inference_config
from ._schema import FIELDS, INFERENCE_FIELDS, Field, schema_table
from ._writer import format_config, write_config

# The modules of the package (all private; everything public is imported here):
#
# * ``_schema``: FIELDS, every key with its type, default, bounds and meaning;
# * ``_core``: load_config (the validation) and the specification classes,
#   load_images, band_psfs;
# * ``_fits``: what is read in FITS files (HDUs, WCS and grids, units, error and
#   weight maps, sky noise, PSF images);
# * ``_infer``: load_inference_config (``lensdual infer``) and its specification classes;
# * ``_values``: angles, sky positions and units, and the words of the messages;
# * ``_writer``: format_config and write_config.

__all__ = [*_core_all, "InferenceConfig", "InferenceSystemSpec", "load_inference_config",
           "format_config", "write_config", "Field", "FIELDS", "INFERENCE_FIELDS",
           "schema_table"]

_INFERENCE_DOC = """
.. rubric:: The keys of lensdual infer

``lensdual infer CONFIG.toml`` turns analysed constellations into a posterior
on the sub-halo abundance (:mod:`lensdual.inference`; the docs page "What the
flags say about dark matter" has an example file).
:func:`load_inference_config` reads its file: an optional ``[output]`` table
(``outdir``, default ``lensdual-inference``), an ``[inference]`` table and one
``[[inference.system]]`` table per constellation. Made from
``INFERENCE_FIELDS`` by :func:`schema_table`.

"""

# The keys of [output] and [analysis] in the example, and the table of keys, come from
# the schema (lensdual run --help prints the example).
__doc__ = (__doc__.replace("@output@", _schema.example("output"))
           .replace("@analysis@", _schema.example("analysis")) + schema_table()
           + _INFERENCE_DOC + schema_table(INFERENCE_FIELDS))

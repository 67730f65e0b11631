"""Warnings and errors specific to lensdual.

Every warning lensdual emits is a `LensdualWarning` (an astropy
``AstropyUserWarning``), every error it defines a `LensdualError` that is
also the builtin error it has always been (`ConfigError` a ``ValueError``,
`OutputConflictError` a ``FileExistsError``, `PipelineError` a
``RuntimeError``), so ``except ValueError`` and ``except LensdualError``
both catch a `ConfigError`. `SameImageError` is a `PipelineError` and a
``ValueError``: the pipeline and `~lensdual.duality.check_duality` raise
it. The classes are importable from here and from the modules that raise
them (``lensdual.config``, ``lensdual.pipeline``, ``lensdual.parametric``).
"""

from pathlib import Path

from astropy.utils.exceptions import AstropyUserWarning

__all__ = [
    "LensdualWarning",
    "EstimatorWarning",
    "NoDetectionsWarning",
    "MissingValuesWarning",
    "LenstoolKeywordWarning",
    "LensdualError",
    "ConfigError",
    "HDUError",
    "OutputConflictError",
    "PipelineError",
    "SameImageError",
]


class LensdualWarning(AstropyUserWarning):
    """Base class of the warnings lensdual emits."""


class EstimatorWarning(LensdualWarning):
    """A size-magnification estimate could not be formed for some pairs.

    The affected values are NaN; the message says which pairs and why.
    """


class NoDetectionsWarning(LensdualWarning):
    """A source finder found nothing in the data; it returns None."""


class MissingValuesWarning(LensdualWarning):
    """Input values that cannot be data are treated as missing.

    A masked flux of a pairs table is "not measured" (NaN), and a pixel whose
    error is zero, negative or not finite is masked; the message names the
    columns and rows, or the file and the number of pixels.
    """


class LenstoolKeywordWarning(LensdualWarning):
    """A keyword of a Lenstool file that lensdual does not interpret and does not know."""


class LensdualError(Exception):
    """Base class of the errors lensdual defines."""


class ConfigError(LensdualError, ValueError):
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


class HDUError(LensdualError, ValueError):
    """A FITS file is unusable, or the HDU asked for does not exist or holds no 2-D image.

    `~lensdual.config.load_config` reports these problems in its `ConfigError`;
    `~lensdual.config.load_images` and `~lensdual.config.band_psfs` raise this
    error for a file that ``load_config`` did not check (a
    `~lensdual.config.RunConfig` made by hand, or a file changed since).

    Parameters
    ----------
    message : str
        What is wrong, naming the file and the HDU.
    on_hdu_key : bool
        True if the problem is the HDU key of the configuration (``hdu``,
        ``error_hdu``, ...), False if it is the file.
    """

    def __init__(self, message, on_hdu_key):
        super().__init__(message)
        self.on_hdu_key = on_hdu_key


class OutputConflictError(LensdualError, FileExistsError):
    """A command would replace a file of its output directory that lensdual did not write.

    Nothing is written then; the message names the file.
    """


class PipelineError(LensdualError, RuntimeError):
    """The analysis cannot go on (no detections, too few pairs, ...)."""


class SameImageError(PipelineError, ValueError):
    """Arcs L1 and L2 are one image: every pair's two images are one point of the sky.

    Raised by :func:`~lensdual.duality.check_duality` and by the pipeline when
    all pairs have their two positions within
    ``lensdual._pairs_table.SAME_IMAGE_SEPARATION`` (1 mas) of each other: an
    identity map, from the same files (or copies of them) given for both
    arcs, or from the L1 positions copied into the L2 columns. Every size
    magnification and flux ratio would be 1 by construction, and "no
    sub-halo" would be a statement about nothing.
    """

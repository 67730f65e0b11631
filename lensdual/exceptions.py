"""Warnings and errors specific to lensdual."""

from astropy.utils.exceptions import AstropyUserWarning

__all__ = ["LensdualWarning", "EstimatorWarning", "NoDetectionsWarning", "MissingValuesWarning"]


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

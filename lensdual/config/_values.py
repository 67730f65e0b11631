"""Reading the values of a configuration: angles, sky positions, units, and the words
of the error messages (a value's description, a did-you-mean suggestion)."""

import difflib
import re

import numpy as np
from astropy import units as u
from astropy.coordinates import SkyCoord


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



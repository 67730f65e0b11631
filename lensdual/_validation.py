"""Input checks shared by the public functions (private module)."""

import numpy as np
from astropy import units as u
from astropy.cosmology import Cosmology, FlatLambdaCDM

__all__ = []

#: The paper's cosmology (flat LambdaCDM, H0 = 70 km/s/Mpc, Om0 = 0.3), used
#: wherever ``cosmology=None``.
DEFAULT_COSMOLOGY = FlatLambdaCDM(H0=70, Om0=0.3)


def as_positions(value, name, *, unit=u.arcsec):
    """Validate an (N, 2) angular Quantity and return it as float64 in ``unit``.

    Raises
    ------
    TypeError
        ``value`` is not a Quantity with angular units.
    ValueError
        Wrong shape, or non-finite entries.
    """
    if not isinstance(value, u.Quantity):
        raise TypeError(
            f"{name} must be an astropy Quantity with angular units (e.g. "
            f"np.array(...) * u.arcsec), got {type(value).__name__}"
        )
    if value.unit.physical_type != "angle":
        raise TypeError(f"{name} must have angular units, got unit {value.unit!s}")
    return as_xy_array(value.to_value(unit), name)


def as_xy_array(value, name):
    """Validate plain (N, 2) finite positions; return a contiguous float64 array."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (N, 2), got shape {arr.shape}")
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        raise ValueError(
            f"{name} contains NaN or infinite positions at row(s) {np.flatnonzero(bad).tolist()}"
        )
    return np.ascontiguousarray(arr)


def as_angle_scalar(value, name, *, unit=u.arcsec, allow_zero=True):
    """Validate a scalar angular Quantity >= 0 (or > 0) and return it in ``unit``."""
    if not isinstance(value, u.Quantity) or value.unit.physical_type != "angle":
        raise TypeError(
            f"{name} must be a scalar Quantity with angular units (e.g. 0.06 * u.arcsec), "
            f"got {value!r}"
        )
    if not value.isscalar:
        raise ValueError(f"{name} must be a scalar, got shape {value.shape}")
    v = float(value.to_value(unit))
    if not np.isfinite(v) or v < 0 or (not allow_zero and v == 0):
        cond = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be finite and {cond}, got {value}")
    return v


def as_int(value, name, *, minimum):
    """Validate an integer >= minimum."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an integer, got {value!r}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value}")
    return int(value)


def as_real(value, name, *, minimum=None, maximum=None, inclusive=True):
    """Validate a finite real number, optionally bounded."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a real number, got {value!r}")
    v = float(value)
    if not np.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value}")
    if minimum is not None and (v < minimum or (not inclusive and v == minimum)):
        raise ValueError(f"{name} must be {'>=' if inclusive else '>'} {minimum}, got {value}")
    if maximum is not None and v > maximum:
        raise ValueError(f"{name} must be <= {maximum}, got {value}")
    return v


def check_unique_rows(arr, name):
    """Raise ValueError if two rows of ``arr`` (N, 2) are identical."""
    _, first, counts = np.unique(arr, axis=0, return_index=True, return_counts=True)
    if (counts > 1).any():
        dup = np.flatnonzero(
            (arr[:, None, :] == arr[None, :, :]).all(axis=2).sum(axis=1) > 1
        )
        raise ValueError(
            f"{name} contains duplicate positions (rows {dup.tolist()}); every point "
            "source of an arc must have its own position"
        )


def as_mass(mass, name="mass"):
    """Validate a (scalar or array) mass Quantity > 0; return it in Msun (Quantity)."""
    if not isinstance(mass, u.Quantity):
        raise TypeError(
            f"{name} must be an astropy Quantity with mass units (e.g. 1e8 * u.Msun), got "
            f"{type(mass).__name__}"
        )
    if mass.unit.physical_type != "mass":
        raise TypeError(f"{name} must have mass units (e.g. u.Msun), got unit {mass.unit!s}")
    value = np.asarray(mass.to_value(u.Msun), dtype=np.float64)
    if not (np.isfinite(value) & (value > 0)).all():
        raise ValueError(f"{name} must be finite and positive, got {mass}")
    return value * u.Msun


def as_cosmology(cosmology):
    """``cosmology``, or :data:`DEFAULT_COSMOLOGY` for None; TypeError otherwise."""
    if cosmology is None:
        return DEFAULT_COSMOLOGY
    if not isinstance(cosmology, Cosmology):
        raise TypeError(
            "cosmology must be an astropy.cosmology.Cosmology instance (e.g. "
            f"astropy.cosmology.Planck18) or None, got {type(cosmology).__name__}"
        )
    return cosmology


def as_redshifts(z_lens, z_source):
    """Validate lens and source redshifts, 0 < z_lens < z_source."""
    zl = as_real(z_lens, "z_lens")
    zs = as_real(z_source, "z_source")
    if zl <= 0:
        raise ValueError(f"z_lens must be > 0, got {z_lens}")
    if zs <= zl:
        raise ValueError(
            f"z_source must be larger than z_lens, got z_source={z_source} <= z_lens={z_lens}"
        )
    return zl, zs


def split_image(image, name):
    """Unpack an image argument by type, with the checks every image needs.

    Accepts an ndarray, a masked array, a Quantity or an NDData/CCDData.
    Returns ``(data, mask, unit, wcs, uncertainty)``: the raw 2-D data array
    (not copied), the mask as an array or None, and the unit, WCS and
    uncertainty or None. Raises TypeError for another type or non-real data,
    ValueError for data that is not 2-D.
    """
    from astropy.nddata import NDData

    mask = unit = wcs = uncertainty = None
    if isinstance(image, NDData):
        data = image.data
        if image.mask is not None:
            mask = np.asarray(image.mask)
        unit, wcs, uncertainty = image.unit, image.wcs, image.uncertainty
    elif isinstance(image, np.ma.MaskedArray):
        data = image.data
        mask = np.ma.getmaskarray(image)
    elif isinstance(image, u.Quantity):
        data = image.value
        unit = image.unit
    elif isinstance(image, np.ndarray):
        data = image
    else:
        raise TypeError(
            f"{name} must be a numpy array, NDData or CCDData (or a masked array or "
            f"Quantity), got {type(image).__name__}"
        )
    data = np.asarray(data)
    if data.dtype.kind not in "iuf":
        raise TypeError(f"{name} must hold real numbers (integer or float), got dtype {data.dtype}")
    if data.ndim != 2:
        raise ValueError(f"{name} must be a 2-D image, got shape {data.shape}")
    return data, mask, unit, wcs, uncertainty

"""Input checks of :mod:`lensdual.sensitivity`: Jacobians, angles, ``r_eff`` grids, sub-haloes."""

import math

import numpy as np
from astropy import units as u

from .._validation import as_int, as_real
from . import _kernels as _k

__all__ = []

_DEFINITIONS = ("paper", "caustic")
_PLANES = ("image", "source")


def _as_jacobian(jacobian, name="jacobian"):
    if isinstance(jacobian, u.Quantity):
        try:
            jacobian = jacobian.to_value(u.dimensionless_unscaled)
        except u.UnitConversionError:
            raise TypeError(f"{name} must be dimensionless, got unit {jacobian.unit!s}") from None
    try:
        a = np.asarray(jacobian, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(
            f"{name} must be a (2, 2) array of real numbers, got {jacobian!r}"
        ) from None
    if a.shape != (2, 2):
        raise ValueError(f"{name} must have shape (2, 2), got shape {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name} must be finite, got {a.tolist()}")
    det = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
    if det == 0.0:
        raise ValueError(f"{name} is singular (det = 0): the macro image lies on a critical curve")
    return a


def _eig(a):
    sym = 0.5 * (a + a.T)
    lam, vec = np.linalg.eigh(sym)
    if (lam == 0).any():
        raise ValueError("jacobian has a zero eigenvalue: the macro image lies on a critical curve")
    return lam, vec


def _choice(value, name, options):
    if not isinstance(value, str) or value not in options:
        raise ValueError(f"{name} must be one of {', '.join(map(repr, options))}, got {value!r}")
    return value


def _as_angle_value(value, name):
    if not isinstance(value, u.Quantity) or value.unit.physical_type != "angle":
        raise TypeError(f"{name} must be a Quantity with angular units, got {value!r}")
    v = np.asarray(value.to_value(u.arcsec), dtype=np.float64)
    if not np.isfinite(v).all():
        raise ValueError(f"{name} must be finite, got {value}")
    return v


def _as_theta_e(theta_e):
    v = _as_angle_value(theta_e, "theta_e")
    if v.ndim != 0 or not v > 0:
        raise ValueError(f"theta_e must be a positive scalar angle, got {theta_e}")
    return float(v)


def _as_offsets(offsets, name="offsets"):
    v = _as_angle_value(offsets, name)
    if v.ndim == 1 and v.shape == (2,):
        v = v[None, :]
    if v.ndim != 2 or v.shape[1] != 2:
        raise ValueError(f"{name} must have shape (N, 2) or (2,), got shape {v.shape}")
    if v.shape[0] == 0:
        raise ValueError(f"{name} is empty")
    return np.ascontiguousarray(v)


def _as_r_eff(r_eff, name="r_eff"):
    try:
        r = np.atleast_1d(np.asarray(r_eff, dtype=np.float64))
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a 1-d array of real numbers, got {r_eff!r}") from None
    if r.ndim != 1 or r.size == 0:
        raise ValueError(f"{name} must be a non-empty 1-d array, got shape {r.shape}")
    if not (np.isfinite(r) & (r >= 0)).all():
        raise ValueError(f"{name} must be finite and >= 0, got {r_eff}")
    return r


def _kwarg_arcsec(kw, key):
    """A lenstronomy kwarg in arcsec: a number, or an angle Quantity converted."""
    value = kw[key]
    if isinstance(value, u.Quantity):
        if value.unit.physical_type != "angle" or not value.isscalar:
            raise ValueError(f"subhalo {key} must be an angle (e.g. 0.02 * u.arcsec) or a "
                             f"number in arcsec, got {value}")
        return float(value.to_value(u.arcsec))
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ValueError(f"subhalo {key} must be a number (arcsec) or an angle Quantity, got "
                         f"{value!r}") from None


def _as_subhalo(subhalo):
    """-> (profile code, p0, p1, p2) from a LensComponent or lenstronomy kwargs."""
    from ..simulation.halos import LensComponent

    profile = None
    if isinstance(subhalo, LensComponent):
        profile, kw = subhalo.profile, subhalo.kwargs
    elif isinstance(subhalo, dict):
        kw = subhalo
        profile = "POINT_MASS" if "theta_E" in kw else "TNFW"
    else:
        raise TypeError(
            "subhalo must be a LensComponent (TNFW or POINT_MASS) or a dict of lenstronomy "
            f"kwargs (Rs, alpha_Rs, r_trunc) or (theta_E), got {type(subhalo).__name__}"
        )
    if profile == "TNFW":
        try:
            rs, ars, rt = (_kwarg_arcsec(kw, k) for k in ("Rs", "alpha_Rs", "r_trunc"))
        except KeyError as err:
            raise ValueError(f"subhalo TNFW kwargs lack {err.args[0]!r}") from None
        for k, v in (("Rs", rs), ("alpha_Rs", ars), ("r_trunc", rt)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"subhalo {k} must be finite and > 0, got {v}")
        return _k.PROFILE_TNFW, rs, _k.tnfw_rho0(rs, ars), rt
    if profile == "POINT_MASS":
        te = _kwarg_arcsec(kw, "theta_E")
        if not (math.isfinite(te) and te > 0):
            raise ValueError(f"subhalo theta_E must be finite and > 0, got {te}")
        return _k.PROFILE_POINT, te, 0.0, 0.0
    raise ValueError(f"subhalo profile must be 'TNFW' or 'POINT_MASS', got {profile!r}")


def _check_grid(box, n_grid):
    box = as_real(box, "box", minimum=0.0, inclusive=False)
    n = as_int(n_grid, "n_grid", minimum=8)
    return box, n

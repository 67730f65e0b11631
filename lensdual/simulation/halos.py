"""Dark-matter haloes from physical parameters, as lenstronomy profiles.

Every builder returns a :class:`LensComponent`: a lenstronomy profile name and
its keyword arguments (angles in arcsec), built from masses and
concentrations with units for a given lens and source redshift.
"""

import numpy as np
from astropy import units as u

from .._lens.component import LensComponent
from .._validation import DEFAULT_COSMOLOGY, as_cosmology, as_mass, as_real, as_redshifts

__all__ = [
    "DEFAULT_COSMOLOGY",
    "LensComponent",
    "mass_concentration",
    "nfw_angular_parameters",
    "tnfw_halo",
    "elliptical_nfw_halo",
    "TRUNCATION_FACTOR",
]

#: Truncation radius of the truncated NFW profiles in units of the scale
#: radius (the paper's Table 1 note: r_t = 30 r_vir / c = 30 r_s).
TRUNCATION_FACTOR = 30.0

# Mass-concentration relation that reproduces the paper's Table 1
# (Maccio et al. 2007 form): c = 10**1.020 (M / 1e12 Msun)**-0.109.
_MCR_LOG10_C0 = 1.020
_MCR_SLOPE = -0.109
_MCR_PIVOT = 1e12


def _as_position(position, name="position"):
    if not isinstance(position, u.Quantity) or position.unit.physical_type != "angle":
        raise TypeError(f"{name} must be an angle Quantity of shape (2,), got {position!r}")
    p = np.asarray(position.to_value(u.arcsec), dtype=float)
    if p.shape != (2,) or not np.isfinite(p).all():
        raise ValueError(f"{name} must be a finite (x, y) pair, got {position}")
    return float(p[0]), float(p[1])


def mass_concentration(mass):
    """Concentration of the paper's mass-concentration relation.

    ``c = 10**1.020 * (M / 1e12 Msun)**-0.109`` (the Maccio et al. 2007 form);
    it gives the concentrations of the paper's Table 1: 9.7 at 2e12, 13.5 at
    1e11, 22.2 at 1e9 and 28.6 at 1e8 Msun.

    Parameters
    ----------
    mass : `~astropy.units.Quantity`
        Halo mass M200 (scalar or array).

    Returns
    -------
    c : float or `~numpy.ndarray`
    """
    m = as_mass(mass).value
    c = 10**_MCR_LOG10_C0 * (m / _MCR_PIVOT) ** _MCR_SLOPE
    return float(c) if np.ndim(c) == 0 else c


def _lens_cosmo(z_lens, z_source, cosmology):
    from lenstronomy.Cosmo.lens_cosmo import LensCosmo

    zl, zs = as_redshifts(z_lens, z_source)
    return LensCosmo(z_lens=zl, z_source=zs, cosmo=as_cosmology(cosmology))


def _concentration(concentration, mass):
    if concentration is None or (isinstance(concentration, str) and concentration == "mcr"):
        return mass_concentration(mass * u.Msun)
    return as_real(concentration, "concentration", minimum=0.0, inclusive=False)


def nfw_angular_parameters(mass, concentration, *, z_lens, z_source, cosmology=None):
    """Angular NFW parameters ``(Rs, alpha_Rs)`` of a halo of mass M200 and concentration c.

    M200 is the mass inside the radius where the mean density is 200 times
    the critical density at ``z_lens`` (lenstronomy's convention, no little h).

    Parameters
    ----------
    mass : `~astropy.units.Quantity`
        M200 (a mass, scalar).
    concentration : float, "mcr" or None
        c200; ``None`` or ``"mcr"`` take it from :func:`mass_concentration`.
    z_lens, z_source : float
        Redshifts (``z_source > z_lens``).
    cosmology : `~astropy.cosmology.Cosmology`, optional
        Defaults to :data:`DEFAULT_COSMOLOGY`.

    Returns
    -------
    Rs, alpha_Rs : `~astropy.units.Quantity`
        Scale radius and deflection at the scale radius, in arcsec.
    """
    m = float(as_mass(mass).value)
    c = _concentration(concentration, m)
    rs, alpha_rs = _lens_cosmo(z_lens, z_source, cosmology).nfw_physical2angle(M=m, c=c)
    return float(rs) * u.arcsec, float(alpha_rs) * u.arcsec


def tnfw_halo(mass, concentration=None, position=(0.0, 0.0) * u.arcsec, *, z_lens, z_source,
              cosmology=None, truncation=TRUNCATION_FACTOR, label="tNFW halo"):
    """A circular truncated NFW halo (lenstronomy ``TNFW``, Baltz et al. 2009).

    Parameters
    ----------
    mass : `~astropy.units.Quantity`
        M200.
    concentration : float, "mcr" or None
        c200; ``None`` or ``"mcr"`` take it from :func:`mass_concentration`.
    position : `~astropy.units.Quantity`, shape (2,)
        Centre in the image plane (arcsec in the lens frame).
    z_lens, z_source : float
        Redshifts (``z_source > z_lens``).
    cosmology : `~astropy.cosmology.Cosmology`, optional
        Defaults to :data:`DEFAULT_COSMOLOGY`.
    truncation : float
        Truncation radius in units of the scale radius (default 30).
    label : str
        Name of the component.

    Returns
    -------
    `LensComponent`
    """
    m = float(as_mass(mass).value)
    c = _concentration(concentration, m)
    trunc = as_real(truncation, "truncation", minimum=0.0, inclusive=False)
    x, y = _as_position(position)
    rs, alpha_rs = nfw_angular_parameters(m * u.Msun, c, z_lens=z_lens, z_source=z_source,
                                          cosmology=cosmology)
    kwargs = {"Rs": rs.value, "alpha_Rs": alpha_rs.value, "r_trunc": trunc * rs.value,
              "center_x": x, "center_y": y}
    meta = {"mass": m * u.Msun, "concentration": c, "truncation": trunc}
    return LensComponent("TNFW", kwargs, label, meta)


def elliptical_nfw_halo(mass, concentration=None, position=(0.0, 0.0) * u.arcsec, *,
                        axis_ratio=1.0, position_angle=0.0 * u.deg, z_lens, z_source,
                        cosmology=None, label="main halo"):
    """An elliptical NFW halo, elliptical in the mass (lenstronomy ``NFW_ELLIPSE_CSE``).

    lenstronomy has no truncated NFW that is elliptical in the mass; the
    truncation of the paper's main halo at 30 r_s (several Mpc for a
    cluster) changes the deflection inside the strong-lensing region by far
    less than the perturbers do, so the untruncated profile is used.

    Parameters
    ----------
    mass, concentration, position, z_lens, z_source, cosmology, label
        As in :func:`tnfw_halo`.
    axis_ratio : float
        Minor-to-major axis ratio q of the convergence, 0 < q <= 1.
    position_angle : `~astropy.units.Quantity`
        Orientation of the major axis, from the x axis towards y.

    Returns
    -------
    `LensComponent`
    """
    from lenstronomy.Util.param_util import phi_q2_ellipticity

    m = float(as_mass(mass).value)
    c = _concentration(concentration, m)
    q = as_real(axis_ratio, "axis_ratio", minimum=0.0, maximum=1.0, inclusive=False)
    if not isinstance(position_angle, u.Quantity) or position_angle.unit.physical_type != "angle":
        raise TypeError(f"position_angle must be an angle Quantity, got {position_angle!r}")
    phi = float(position_angle.to_value(u.rad))
    x, y = _as_position(position)
    rs, alpha_rs = nfw_angular_parameters(m * u.Msun, c, z_lens=z_lens, z_source=z_source,
                                          cosmology=cosmology)
    e1, e2 = phi_q2_ellipticity(phi, q)
    kwargs = {"Rs": rs.value, "alpha_Rs": alpha_rs.value, "e1": float(e1), "e2": float(e2),
              "center_x": x, "center_y": y}
    meta = {"mass": m * u.Msun, "concentration": c, "axis_ratio": q,
            "position_angle": position_angle}
    return LensComponent("NFW_ELLIPSE_CSE", kwargs, label, meta)

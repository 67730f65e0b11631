"""``r_eff``: the unit ellipse of a sub-halo at a macro image and offsets on it (paper Fig. 7)."""

import math

import numpy as np
from astropy import units as u

from ._inputs import (
    _DEFINITIONS,
    _PLANES,
    _as_angle_value,
    _as_jacobian,
    _as_offsets,
    _as_r_eff,
    _as_theta_e,
    _choice,
    _eig,
)

__all__ = ["effective_radius_ellipse", "effective_radius", "offsets_on_ellipse"]


def _unit_map(a, te, definition):
    """2x2 matrix M with image-plane unit-ellipse offsets ``d = M (cos phi, sin phi)``."""
    if definition == "paper":
        return te * np.eye(2)
    lam, vec = _eig(a)
    return vec * (2.0 * te / np.sqrt(np.abs(lam)))[None, :]


def _orientation(v):
    ang = math.degrees(math.atan2(v[1], v[0]))
    if ang <= -90:
        ang += 180
    elif ang > 90:
        ang -= 180
    return ang


def effective_radius_ellipse(jacobian, theta_e, *, definition="paper", plane="source"):
    """The unit ellipse ``r_eff = 1`` of a sub-halo at a macro image (paper Fig. 7).

    Parameters
    ----------
    jacobian : array_like, shape (2, 2)
        Macro Jacobian ``A0 = d beta / d theta`` at the image.
    theta_e : `~astropy.units.Quantity`
        Isolated Einstein radius of the sub-halo (the paper: the point-mass
        Einstein radius of its M200, :func:`lensdual.abundance.einstein_radius`).
    definition : {"paper", "caustic"}
        ``"paper"``: the Einstein ring mapped by ``A0`` (a circle of radius
        ``theta_E`` in the image plane); ``"caustic"``: image-plane
        semi-axes ``2 theta_E / sqrt(|lambda_i|)`` along the eigenvectors of
        ``A0`` (see the module docstring).
    plane : {"source", "image"}
        ``"source"``: the ellipse of source positions relative to the
        sub-halo mapped by the macro model (the ellipse drawn in Fig. 7),
        i.e. ``A0`` applied to the image-plane ellipse; ``"image"``: the
        ellipse of image-plane offsets ``d`` of the sub-halo from the macro
        image.

    Returns
    -------
    semi_axes : `~astropy.units.Quantity`, shape (2,)
        Major and minor semi-axis (arcsec).
    orientation : `~astropy.units.Quantity`
        Angle of the major axis from the x axis (deg, in (-90, 90]).

    Examples
    --------
    For the SMACS0723 analogue's L2 image (eigenvalues -0.635 and 0.223)
    the paper's unit ellipse in the source plane has semi-axes
    ``|lambda_i| theta_E``:

    >>> import numpy as np
    >>> import astropy.units as u
    >>> from lensdual.sensitivity import effective_radius_ellipse
    >>> A0 = np.diag([-0.635, 0.223])
    >>> axes, angle = effective_radius_ellipse(A0, 0.0232 * u.arcsec)
    >>> print(np.round(axes / (0.0232 * u.arcsec), 3), angle)
    [0.635 0.223] 0.0 deg
    """
    a = _as_jacobian(jacobian)
    te = _as_theta_e(theta_e)
    _choice(definition, "definition", _DEFINITIONS)
    _choice(plane, "plane", _PLANES)
    m = _unit_map(a, te, definition)
    if plane == "source":
        m = a @ m
    uu, s, _ = np.linalg.svd(m)
    return s * u.arcsec, _orientation(uu[:, 0]) * u.deg


def effective_radius(offsets, jacobian, theta_e, *, definition="paper", plane="image"):
    """``r_eff`` of sub-halo offsets (see :func:`effective_radius_ellipse`).

    Parameters
    ----------
    offsets : `~astropy.units.Quantity`, shape (N, 2) or (2,)
        ``plane="image"``: sub-halo centre minus macro image position;
        ``plane="source"``: source position minus the sub-halo centre
        mapped to the source plane by the macro model (``-A0 d``).
    jacobian : array_like, shape (2, 2)
    theta_e : `~astropy.units.Quantity`
    definition : {"paper", "caustic"}
    plane : {"image", "source"}

    Returns
    -------
    r_eff : `~numpy.ndarray`, shape (N,)

    Examples
    --------
    >>> import numpy as np
    >>> import astropy.units as u
    >>> from lensdual.sensitivity import effective_radius
    >>> A0 = np.diag([-0.25, 0.64])
    >>> d = [[0.08, 0.0], [0.0, 0.05]] * u.arcsec
    >>> effective_radius(d, A0, 0.02 * u.arcsec)
    array([4. , 2.5])
    >>> effective_radius(d, A0, 0.02 * u.arcsec, definition="caustic")
    array([1., 1.])
    """
    d = _as_offsets(offsets)
    a = _as_jacobian(jacobian)
    te = _as_theta_e(theta_e)
    _choice(definition, "definition", _DEFINITIONS)
    _choice(plane, "plane", _PLANES)
    if plane == "source":
        d = -np.linalg.solve(a, d.T).T
    m = _unit_map(a, te, definition)
    return np.hypot(*np.linalg.solve(m, d.T))


def offsets_on_ellipse(r_eff, angles, jacobian, theta_e, *, definition="paper"):
    """Image-plane sub-halo offsets ``d`` with the given ``r_eff`` at the given angles.

    ``definition="paper"``: ``d = r_eff theta_E (cos(phi), sin(phi))``, ``phi``
    the polar angle from the x axis; ``"caustic"``:
    ``d = r_eff (a_1 cos(phi) e_1 + a_2 sin(phi) e_2)``, ``phi`` the
    parametric angle from the first eigenvector (ascending eigenvalue).

    Parameters
    ----------
    r_eff : array_like
        Non-empty 1-d, >= 0.
    angles : `~astropy.units.Quantity`
        Angles (1-d or scalar).
    jacobian, theta_e, definition
        As in :func:`effective_radius_ellipse`.

    Returns
    -------
    offsets : `~astropy.units.Quantity`, shape (len(r_eff) * len(angles), 2)
        r_eff varies slowest.

    Examples
    --------
    >>> import numpy as np
    >>> import astropy.units as u
    >>> from lensdual.sensitivity import offsets_on_ellipse
    >>> A0 = np.diag([-0.25, 0.64])
    >>> offsets_on_ellipse([1.0, 2.0], [0, 90] * u.deg, A0, 0.02 * u.arcsec).round(3)
    <Quantity [[0.02, 0.  ],
               [0.  , 0.02],
               [0.04, 0.  ],
               [0.  , 0.04]] arcsec>

    With ``definition="caustic"`` the semi-axes are ``2 theta_E / sqrt(|lambda_i|)``:

    >>> offsets_on_ellipse([1.0], [0, 90] * u.deg, A0, 0.02 * u.arcsec,
    ...                    definition="caustic").round(3)
    <Quantity [[0.08, 0.  ],
               [0.  , 0.05]] arcsec>
    """
    r = _as_r_eff(r_eff)
    phi = np.atleast_1d(_as_angle_value(angles, "angles") * (math.pi / 180 / 3600))
    a = _as_jacobian(jacobian)
    te = _as_theta_e(theta_e)
    _choice(definition, "definition", _DEFINITIONS)
    base = np.stack([np.cos(phi), np.sin(phi)], axis=1) @ _unit_map(a, te, definition).T
    return (r[:, None, None] * base[None, :, :]).reshape(-1, 2) * u.arcsec

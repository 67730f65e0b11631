r"""Rough upper limits on the abundance of sub-haloes (paper Sect. 5.3).

A sub-halo of mass :math:`M` can only make a point source break geometrical
duality if the source lies within a few Einstein radii, :math:`\zeta\theta_E`,
of it. Finding no anomalous pair among :math:`n` point sources then bounds the
per-source detection probability :math:`p_{\rm det}` (a binomial experiment),
and through :math:`p_{\rm det} = \Sigma_{\rm sub}\,\pi(\zeta\theta_E)^2` the
surface number density :math:`\Sigma_{\rm sub}` of such sub-haloes. The three
steps are :func:`einstein_radius` (and :func:`einstein_radius_physical`),
:func:`detection_probability_limit` and :func:`surface_density_limit`.

This is the paper's "very rough estimate": it ignores selection effects, the
enlargement of the Einstein radius by the host's magnification, and the
spread of sub-halo masses.
"""

import numpy as np
from astropy import constants as const
from astropy import units as u

from ._validation import as_cosmology, as_int, as_mass, as_real, as_redshifts

__all__ = [
    "einstein_radius",
    "einstein_radius_physical",
    "detection_probability_limit",
    "surface_density_limit",
]

_METHODS = ("paper", "exact")


def _einstein_radius_rad(mass, z_lens, z_source, cosmology):
    """Validated inputs -> (theta_E in radians as a float array, D_l)."""
    mass = as_mass(mass)
    zl, zs = as_redshifts(z_lens, z_source)
    cosmo = as_cosmology(cosmology)
    d_l = cosmo.angular_diameter_distance(zl)
    d_s = cosmo.angular_diameter_distance(zs)
    d_ls = cosmo.angular_diameter_distance(zl, zs)
    theta2 = (4 * const.G * mass / const.c**2 * d_ls / (d_l * d_s)).to_value(
        u.dimensionless_unscaled
    )
    return np.sqrt(theta2), d_l


def einstein_radius(mass, z_lens, z_source, cosmology=None):
    r"""Einstein radius of a point mass, as an angle (paper Eq. einstein-radius).

    .. math::

       \theta_E = \left(\frac{4GM}{c^2}\frac{D_{ls}}{D_l D_s}\right)^{1/2}

    with :math:`D_l`, :math:`D_s` and :math:`D_{ls}` the angular-diameter
    distances to the lens, to the source and from the lens to the source.

    Parameters
    ----------
    mass : `~astropy.units.Quantity`
        Mass of the point-like (sub-)halo, any mass unit; scalar or array,
        every element finite and > 0.
    z_lens : float
        Redshift of the lens, > 0.
    z_source : float
        Redshift of the source, > ``z_lens``.
    cosmology : `~astropy.cosmology.Cosmology`, optional
        Cosmology of the distances. Default
        ``FlatLambdaCDM(H0=70, Om0=0.3)``.

    Returns
    -------
    theta_E : `~astropy.units.Quantity`
        Einstein radius in arcsec, with the shape of ``mass``.

    Raises
    ------
    TypeError
        ``mass`` is not a Quantity with mass units, a redshift is not a real
        number, or ``cosmology`` is not an astropy cosmology.
    ValueError
        ``mass`` is not finite and positive, ``z_lens <= 0`` or
        ``z_source <= z_lens``.

    See Also
    --------
    einstein_radius_physical : the same radius as a length at the lens.

    Notes
    -----
    :math:`\theta_E \propto M^{1/2}`. For the paper's configuration
    (:math:`z_l = 0.39`, :math:`z_s = 2.2`) and the default cosmology,
    :math:`\theta_E = 0.02321\,(M/10^8 M_\odot)^{1/2}` arcsec, which the paper
    quotes as 0.0232 arcsec. The effective Einstein radius of a sub-halo in
    a macro-magnified region is larger (by about :math:`\sqrt{\mu_{\rm size}}`);
    that factor is not included.

    Examples
    --------
    >>> import astropy.units as u
    >>> from lensdual.abundance import einstein_radius
    >>> print(f"{einstein_radius(1e8 * u.Msun, 0.39, 2.2):.4f}")
    0.0232 arcsec
    """
    theta, _ = _einstein_radius_rad(mass, z_lens, z_source, cosmology)
    return (theta * u.rad).to(u.arcsec)


def einstein_radius_physical(mass, z_lens, z_source, cosmology=None):
    r"""Einstein radius of a point mass, as a proper length at the lens.

    :math:`R_E = \theta_E D_l`, with :math:`\theta_E` from
    :func:`einstein_radius` and :math:`D_l` the angular-diameter distance to
    the lens (so a proper, not comoving, length).

    Parameters
    ----------
    mass : `~astropy.units.Quantity`
        Mass of the point-like (sub-)halo, any mass unit; scalar or array,
        every element finite and > 0.
    z_lens : float
        Redshift of the lens, > 0.
    z_source : float
        Redshift of the source, > ``z_lens``.
    cosmology : `~astropy.cosmology.Cosmology`, optional
        Cosmology of the distances. Default
        ``FlatLambdaCDM(H0=70, Om0=0.3)``.

    Returns
    -------
    R_E : `~astropy.units.Quantity`
        Einstein radius in kpc, with the shape of ``mass``.

    Raises
    ------
    TypeError, ValueError
        As :func:`einstein_radius`.

    Notes
    -----
    At :math:`z_l = 0.39` in the default cosmology 1 arcsec is 5.290 kpc, so
    the :math:`10^8 M_\odot` Einstein radius of 0.0232 arcsec is 0.1228 kpc.
    The paper quotes 0.388 kpc for it, which is instead the Einstein radius
    of a :math:`10^9 M_\odot` point mass (:math:`0.1228 \sqrt{10}`); see
    :func:`surface_density_limit`.

    Examples
    --------
    >>> import astropy.units as u
    >>> from lensdual.abundance import einstein_radius_physical
    >>> print(f"{einstein_radius_physical(1e8 * u.Msun, 0.39, 2.2):.4f}")
    0.1228 kpc
    """
    theta, d_l = _einstein_radius_rad(mass, z_lens, z_source, cosmology)
    return (theta * d_l).to(u.kpc)


def detection_probability_limit(n_sources, n_arcs=2, confidence=0.95, method="paper"):
    r"""Upper limit on the per-source detection probability after no detection.

    Each of the :math:`n = n_{\rm arcs} n_{\rm sources}` point-source images
    is a Bernoulli trial that "detects" a sub-halo with probability
    :math:`p_{\rm det}`. If none does, :math:`p_{\rm det}` is bounded by

    .. math::

       p_{\rm det} < 1 - (\Delta/2)^{1/n} \quad (\text{method="paper"}), \qquad
       p_{\rm det} < 1 - \Delta^{1/n} \quad (\text{method="exact"}),

    with :math:`\Delta = 1 - \text{confidence}`.

    Parameters
    ----------
    n_sources : int
        Number of point sources per arc, >= 1 (12 in the paper).
    n_arcs : int, optional
        Number of arcs (multiple images) each source is seen on, >= 1.
        Default 2.
    confidence : float, optional
        Confidence level, strictly between 0 and 1. Default 0.95.
    method : {"paper", "exact"}, optional
        ``"paper"`` (default): the paper's bound with :math:`\Delta/2`.
        ``"exact"``: the exact one-sided upper limit with :math:`\Delta`.

    Returns
    -------
    p_limit : float
        Upper limit on :math:`p_{\rm det}`.

    Raises
    ------
    TypeError
        ``n_sources`` or ``n_arcs`` is not an integer, or ``confidence`` is
        not a real number.
    ValueError
        ``n_sources`` or ``n_arcs`` is < 1, ``confidence`` is not strictly
        between 0 and 1, or ``method`` is unknown.

    Notes
    -----
    With zero successes in :math:`n` trials the probability of the observed
    outcome is :math:`(1 - p)^n`. The exact one-sided upper limit at
    confidence :math:`1 - \Delta` is the :math:`p` at which that probability
    falls to :math:`\Delta`: :math:`p < 1 - \Delta^{1/n}` (0.1173 for
    :math:`n = 24` at 95 per cent); this is ``method="exact"``.

    The paper uses :math:`\Delta/2` instead, the upper end of a two-sided
    (Clopper-Pearson) interval at confidence :math:`1 - \Delta`, which puts
    :math:`\Delta/2` in each tail; for zero successes the lower end is 0, so
    this is also the one-sided limit at confidence :math:`1 - \Delta/2`
    (97.5 per cent). It is the more conservative (larger) bound: 0.1425 for
    :math:`n = 24` at 95 per cent, quoted as 0.142 in the paper.

    Examples
    --------
    >>> from lensdual.abundance import detection_probability_limit
    >>> print(f"{detection_probability_limit(12):.4f}")
    0.1425
    >>> print(f"{detection_probability_limit(12, method='exact'):.4f}")
    0.1173
    """
    n_sources = as_int(n_sources, "n_sources", minimum=1)
    n_arcs = as_int(n_arcs, "n_arcs", minimum=1)
    conf = as_real(confidence, "confidence")
    if not 0 < conf < 1:
        raise ValueError(f"confidence must be strictly between 0 and 1, got {confidence}")
    if not isinstance(method, str) or method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    delta = 1.0 - conf
    tail = delta / 2 if method == "paper" else delta
    n = n_arcs * n_sources
    # 1 - tail**(1/n), accurate also when the result is tiny.
    return float(-np.expm1(np.log(tail) / n))


def surface_density_limit(p_det, mass, *, z_lens, z_source, zeta=3, cosmology=None):
    r"""Upper limit on the surface number density of sub-haloes of one mass.

    A point source is affected by a sub-halo (mass :math:`M`) if it lies
    within :math:`\zeta R_E` of it, :math:`R_E` being the sub-halo's
    Einstein radius as a length at the lens. For sub-haloes of surface density
    :math:`\Sigma_{\rm sub}`, :math:`p_{\rm det} = \Sigma_{\rm sub}\,\pi(\zeta
    R_E)^2`, so an upper limit on :math:`p_{\rm det}` gives

    .. math::

       \Sigma_{\rm sub} < \frac{p_{\rm det}}{\pi (\zeta R_E)^2}.

    Parameters
    ----------
    p_det : float
        Upper limit on the per-source detection probability, in (0, 1]; e.g.
        from :func:`detection_probability_limit`.
    mass : `~astropy.units.Quantity`
        Sub-halo mass, any mass unit; scalar or array, every element finite
        and > 0.
    z_lens : float
        Redshift of the lens, > 0.
    z_source : float
        Redshift of the source, > ``z_lens``.
    zeta : float, optional
        Detection radius in Einstein radii, > 0. Default 3 (the paper's
        choice).
    cosmology : `~astropy.cosmology.Cosmology`, optional
        Cosmology of the distances. Default
        ``FlatLambdaCDM(H0=70, Om0=0.3)``.

    Returns
    -------
    sigma_limit : `~astropy.units.Quantity`
        Upper limit on :math:`\Sigma_{\rm sub}` in kpc\ :sup:`-2` (proper
        area at the lens), with the shape of ``mass``.

    Raises
    ------
    TypeError
        ``p_det`` or ``zeta`` is not a real number, or as
        :func:`einstein_radius`.
    ValueError
        ``p_det`` is not in (0, 1], ``zeta`` is not finite and > 0, or as
        :func:`einstein_radius`.

    Notes
    -----
    The paper quotes :math:`\theta_E = 0.0232` arcsec :math:`= 0.388` kpc
    for :math:`10^8 M_\odot` at :math:`z_l = 0.39`, :math:`z_s = 2.2`, and
    :math:`\Sigma_{\rm sub} < 0.300` kpc\ :sup:`-2`. But 0.0232 arcsec at
    :math:`z_l = 0.39` is 0.1228 kpc (5.290 kpc per arcsec); 0.388 kpc is the
    Einstein radius of :math:`10^9 M_\odot`. The paper's number is
    :math:`0.142 / (\pi\, 0.388^2) = 0.300`, i.e. it corresponds to
    :math:`\zeta = 1` with 0.388 kpc (equivalently :math:`\zeta = 1`,
    :math:`M = 10^9 M_\odot`), not to the stated :math:`\zeta = 3`. The
    consistent values for :math:`10^8 M_\odot` with :math:`p_{\rm det} <
    0.1425` are 0.334 kpc\ :sup:`-2` for :math:`\zeta = 3` (close to the
    paper's 0.300 by coincidence, since :math:`3 \times 0.1228 = 0.368
    \approx 0.388`) and 3.01 kpc\ :sup:`-2` for :math:`\zeta = 1`.

    The linear relation :math:`p_{\rm det} = \Sigma_{\rm sub}\pi(\zeta R_E)^2`
    (the paper's) is the small-:math:`p` limit of the Poisson probability
    :math:`1 - \exp[-\Sigma_{\rm sub}\pi(\zeta R_E)^2]` of having at least
    one sub-halo within :math:`\zeta R_E`. The Poisson form would give the
    looser (more conservative) limit :math:`\Sigma_{\rm sub} <
    -\ln(1 - p_{\rm det}) / [\pi(\zeta R_E)^2]`, larger by 8 per cent for
    :math:`p_{\rm det} = 0.1425`; like the paper, this function uses the
    linear form.

    Examples
    --------
    >>> import astropy.units as u
    >>> from lensdual.abundance import detection_probability_limit, surface_density_limit
    >>> p = detection_probability_limit(12)
    >>> sigma = surface_density_limit(p, 1e8 * u.Msun, z_lens=0.39, z_source=2.2)
    >>> print(f"{sigma:.3f}")
    0.334 1 / kpc2
    """
    p = as_real(p_det, "p_det")
    if not 0 < p <= 1:
        raise ValueError(f"p_det must be in (0, 1], got {p_det}")
    z = as_real(zeta, "zeta")
    if not z > 0:
        raise ValueError(f"zeta must be > 0, got {zeta}")
    radius = einstein_radius_physical(mass, z_lens, z_source, cosmology=cosmology)
    return (p / (np.pi * (z * radius) ** 2)).to(u.kpc**-2)

"""Ready-made lens systems: the SMACS0723 analogue of the paper's Table 1."""

import numpy as np
from astropy import units as u

from .._pairs_table import arc_xy
from .._validation import as_int
from .halos import LensComponent, elliptical_nfw_halo, tnfw_halo
from .lens_system import LensSystem

__all__ = ["SMACS0723", "SUBHALOES", "smacs0723_analog"]

#: Parameters of the SMACS0723 analogue (paper Table 1, with the main halo's
#: concentration changed, see :func:`smacs0723_analog`).
SMACS0723 = {
    "z_lens": 0.39,
    "z_source": 2.2,
    "main_mass": 5e14 * u.Msun,
    "main_concentration": 9.6,
    "main_axis_ratio": 0.85,
    "source_centre": (0.69, 6.99) * u.arcsec,
    "source_sigma": 0.06 * u.arcsec,
    # (mass, concentration, image-plane position) of the two cluster members
    "members": (
        (2e12 * u.Msun, 9.7, (4.1, -6.4) * u.arcsec),
        (1e11 * u.Msun, 13.5, (-3.8, -6.8) * u.arcsec),
    ),
}

#: The paper's three sub-haloes: (mass, concentration); ``None`` = on the
#: mass-concentration relation (22.2 and 28.6).
SUBHALOES = {
    "massive": (1e9 * u.Msun, None),
    "small": (1e8 * u.Msun, None),
    "overconcentrated": (1e8 * u.Msun, 100.0),
}


def smacs0723_analog(*, perturbers=False, subhalo=None, n_sources=16, seed=None,
                     subhalo_source=0, subhalo_offset=(0.0, 0.0) * u.arcsec):
    """The SMACS0723-like lens of the paper's Table 1, with its constellation.

    Main halo: elliptical NFW (elliptical in the mass), M200 = 5e14 Msun,
    axis ratio 0.85, at z = 0.39, source at z = 2.2; 16 point sources drawn
    from a Gaussian of sigma 0.06 arcsec around (0.69, 6.99) arcsec in the
    source plane (lens-centred frame).

    What differs from Table 1: the paper's main-halo concentration c = 0.26
    gives a scale radius of ~1000 arcsec and no multiple images at all with
    the standard M200-c conversion. Keeping the mass, the axis ratio and the
    source distribution, lensdual uses c = 9.6, the value for which the
    paper's source centre lies 0.2 arcsec inside the fold of the radial
    caustic (the outer caustic of the NFW's shallow core), so that the
    constellation is imaged twice on a fold pair of opposite parity (arcs L1,
    positive, and L2, negative parity, on both sides of the radial critical
    curve), with a third, weakly magnified image near the tangential
    critical curve (Einstein radius ~21 arcsec). The main halo is not
    truncated (lenstronomy has no truncated NFW that is elliptical in the
    mass); at 30 r_s the truncation lies several Mpc out and does not
    affect the arcs.

    Parameters
    ----------
    perturbers : bool
        Add the two cluster members of Table 1, truncated NFW haloes
        (2e12 Msun, c = 9.7) and (1e11 Msun, c = 13.5), a few arcsec from the
        arcs (positions in :data:`SMACS0723`).
    subhalo : {None, "massive", "small", "overconcentrated"} or LensComponent
        Add the named sub-halo of Table 1 (truncated NFW: 1e9 Msun on the
        mass-concentration relation, 1e8 Msun on it, 1e8 Msun with c = 100),
        centred on the L2 image of source ``subhalo_source`` (plus
        ``subhalo_offset``), found in the system without it; or any
        component, as given.
    n_sources : int
        Number of point sources of the constellation (default 16).
    seed : int, `numpy.random.Generator` or None
        Seed of the source positions.
    subhalo_source : int
        Which source's L2 image the sub-halo sits on.
    subhalo_offset : `~astropy.units.Quantity`, shape (2,)
        Offset of the sub-halo from that image.

    Returns
    -------
    system : `~lensdual.simulation.LensSystem`
        With ``system.sources`` the (n_sources, 2) source positions, so that
        ``system.constellation()`` gives the pairs table.
    """
    n = as_int(n_sources, "n_sources", minimum=3)
    rng = np.random.default_rng(seed)
    p = SMACS0723
    zl, zs = p["z_lens"], p["z_source"]
    centre = p["source_centre"].to_value(u.arcsec)
    sigma = p["source_sigma"].to_value(u.arcsec)
    sources = (centre + sigma * rng.standard_normal((n, 2))) * u.arcsec

    comps = [elliptical_nfw_halo(p["main_mass"], p["main_concentration"],
                                 axis_ratio=p["main_axis_ratio"], z_lens=zl, z_source=zs)]
    if not isinstance(perturbers, bool):
        raise TypeError(f"perturbers must be True or False, got {perturbers!r}")
    if perturbers:
        for i, (mass, conc, pos) in enumerate(p["members"], start=1):
            comps.append(tnfw_halo(mass, conc, pos, z_lens=zl, z_source=zs,
                                   label=f"cluster member {i}"))
    system = LensSystem(comps, z_lens=zl, z_source=zs, sources=sources)
    if subhalo is None:
        return system
    if isinstance(subhalo, LensComponent):
        return system.add(subhalo)
    if not isinstance(subhalo, str) or subhalo not in SUBHALOES:
        raise ValueError(f"subhalo must be None, a LensComponent or one of {sorted(SUBHALOES)}, "
                         f"got {subhalo!r}")
    k = as_int(subhalo_source, "subhalo_source", minimum=0)
    if k >= n:
        raise ValueError(f"subhalo_source must be < n_sources = {n}, got {k}")
    pairs = system.constellation()
    row = np.flatnonzero(np.asarray(pairs["source"]) == k)
    if row.size == 0:
        raise ValueError(f"source {k} has no image on both arcs; choose another subhalo_source")
    host = arc_xy(pairs, 2)[row[0]]
    offset = u.Quantity(subhalo_offset, u.arcsec).value
    mass, conc = SUBHALOES[subhalo]
    sub = tnfw_halo(mass, conc, (host + offset) * u.arcsec, z_lens=zl, z_source=zs,
                    label=f"{subhalo} sub-halo")
    return system.add(sub)

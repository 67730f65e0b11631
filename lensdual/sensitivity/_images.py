"""Micro-images and the flux excess of a macro image perturbed by a sub-halo (paper Fig. 8)."""

import math

import numpy as np
from astropy import units as u
from astropy.table import QTable

from .._validation import as_int
from . import _kernels as _k
from ._inputs import _as_jacobian, _as_offsets, _as_r_eff, _as_subhalo, _check_grid, _eig
from ._radius import offsets_on_ellipse

__all__ = ["subhalo_einstein_radius", "micro_images", "flux_excess", "flux_excess_distribution"]

_MAX_IMAGES = 16


def subhalo_einstein_radius(subhalo):
    """Point-mass Einstein radius of a sub-halo's total projected mass.

    ``theta_E = sqrt(r alpha(r))`` for ``r -> infinity`` (``1e4 r_trunc``
    for a TNFW), or ``theta_E`` of a point mass. The paper normalises
    ``r_eff`` to the Einstein radius of M200 instead
    (:func:`lensdual.abundance.einstein_radius`), which
    :func:`detection_snr_map` uses; a TNFW truncated at 30 ``Rs`` holds
    more than M200.

    Parameters
    ----------
    subhalo : `~lensdual.simulation.LensComponent` or dict
        ``TNFW`` (lenstronomy kwargs ``Rs, alpha_Rs, r_trunc``) or
        ``POINT_MASS`` (``theta_E``).

    Returns
    -------
    theta_E : `~astropy.units.Quantity`
        arcsec.

    Examples
    --------
    >>> import astropy.units as u
    >>> from lensdual.sensitivity import subhalo_einstein_radius
    >>> subhalo_einstein_radius({"theta_E": 0.02})
    <Quantity 0.02 arcsec>
    >>> theta_e = subhalo_einstein_radius({"Rs": 0.01, "alpha_Rs": 0.002, "r_trunc": 0.3})
    >>> round(float(theta_e.to_value(u.arcsec)), 4)
    0.0128
    """
    code, p0, p1, p2 = _as_subhalo(subhalo)
    return _te(code, p0, p1, p2) * u.arcsec


def _te(code, p0, p1, p2):
    if code == _k.PROFILE_POINT:
        return p0
    r = 1e4 * p2
    return math.sqrt(r * _k.deflection_hessian(code, p0, p1, p2, r, 0.0)[0])


def _box(a, code, p0, p1, p2, box):
    lam, _ = _eig(a)
    return box * _te(code, p0, p1, p2) / math.sqrt(np.abs(lam).min())


def _grid(a, code, p0, p1, p2, half_width, n):
    gx = np.empty((n + 1, n + 1))
    gy = np.empty((n + 1, n + 1))
    _k.source_grid(a[0, 0], a[0, 1], a[1, 0], a[1, 1], code, p0, p1, p2, half_width, n, gx, gy)
    return gx, gy


def micro_images(jacobian, subhalo, offset, *, box=10.0, n_grid=400):
    """All images of the local lens equation for one sub-halo offset.

    Parameters
    ----------
    jacobian : array_like, shape (2, 2)
        Macro ``A0 = d beta / d theta`` at the macro image.
    subhalo : `~lensdual.simulation.LensComponent` or dict
        Circular ``TNFW`` (lenstronomy kwargs ``Rs, alpha_Rs, r_trunc``; the
        centre is ignored) or ``POINT_MASS`` (``theta_E``).
    offset : `~astropy.units.Quantity`, shape (2,)
        Sub-halo centre minus the macro image position.
    box : float
        Half-width of the search box around the sub-halo, in units of
        ``theta_E / sqrt(min |lambda_i|)`` (default 10).
    n_grid : int
        Cells per side of the search grid (default 400).

    Returns
    -------
    images : `~astropy.table.QTable`
        ``x``, ``y`` (image position minus macro image position, arcsec) and
        ``mu`` (signed magnification), sorted by ``|mu|`` descending.

    Examples
    --------
    A point mass (``theta_E = 0.02`` arcsec) in an isotropic macro field
    ``A0 = 0.5 I`` at ``|d| = theta_E / sqrt(0.5)``: the two images of the
    rescaled point lens at impact parameter 1, of total magnification
    ``|mu_0| 3 / sqrt(5)`` with ``mu_0 = 1 / det A0 = 4``:

    >>> import numpy as np
    >>> import astropy.units as u
    >>> from lensdual.sensitivity import micro_images
    >>> d = [0.02 / np.sqrt(0.5), 0.0] * u.arcsec
    >>> images = micro_images(0.5 * np.eye(2), {"theta_E": 0.02}, d)
    >>> len(images), np.round(images["mu"], 3).tolist()
    (2, [4.683, -0.683])
    >>> round(float(np.abs(images["mu"]).sum() / 4), 4)
    1.3416
    """
    a = _as_jacobian(jacobian)
    code, p0, p1, p2 = _as_subhalo(subhalo)
    d = _as_offsets(offset, "offset")
    if d.shape[0] != 1:
        raise ValueError(f"offset must be a single (2,) offset, got shape {d.shape}")
    box, n = _check_grid(box, n_grid)
    h = _box(a, code, p0, p1, p2, box)
    gx, gy = _grid(a, code, p0, p1, p2, h, n)
    pos = np.empty((_MAX_IMAGES, 2))
    mu = np.empty(_MAX_IMAGES)
    m = _k.solve_offset(a[0, 0], a[0, 1], a[1, 0], a[1, 1], code, p0, p1, p2, d[0, 0], d[0, 1],
                        h, n, gx, gy, pos, mu)
    order = np.argsort(-np.abs(mu[:m]))
    xy = pos[:m][order] + d[0]
    return QTable({"x": xy[:, 0] * u.arcsec, "y": xy[:, 1] * u.arcsec, "mu": mu[:m][order]})


def _flux_excess_raw(a, code, p0, p1, p2, d, box, n):
    h = _box(a, code, p0, p1, p2, box)
    gx, gy = _grid(a, code, p0, p1, p2, h, n)
    excess = np.empty(d.shape[0])
    counts = np.empty(d.shape[0], dtype=np.int64)
    _k.flux_excess_many(a[0, 0], a[0, 1], a[1, 0], a[1, 1], code, p0, p1, p2, d, h, n, gx, gy,
                        _MAX_IMAGES, excess, counts)
    return excess, counts


def flux_excess(jacobian, subhalo, offsets, *, box=10.0, n_grid=400, return_counts=False):
    """Total flux magnification over the macro one, ``sum_i |mu_i| |det A0|``.

    Parameters
    ----------
    jacobian, subhalo, box, n_grid
        As in :func:`micro_images` (one grid serves all offsets).
    offsets : `~astropy.units.Quantity`, shape (N, 2) or (2,)
        Sub-halo centre minus macro image position.
    return_counts : bool
        Also return the number of micro-images per offset.

    Returns
    -------
    excess : `~numpy.ndarray`, shape (N,)
    counts : `~numpy.ndarray` of int, shape (N,)
        Only with ``return_counts=True``.

    Examples
    --------
    A point mass in an isotropic field ``A0 = 0.5 I`` at ``|d| = theta_E /
    sqrt(0.5)`` (impact parameter u = 1 of the rescaled point lens; the
    point-lens magnification ``3 / sqrt(5)``):

    >>> import numpy as np
    >>> import astropy.units as u
    >>> from lensdual.sensitivity import flux_excess
    >>> d = [0.02 / np.sqrt(0.5), 0.0] * u.arcsec
    >>> fe, n = flux_excess(0.5 * np.eye(2), {"theta_E": 0.02}, d, return_counts=True)
    >>> print(f"{fe[0]:.4f} with {n[0]} images")
    1.3416 with 2 images
    """
    a = _as_jacobian(jacobian)
    code, p0, p1, p2 = _as_subhalo(subhalo)
    d = _as_offsets(offsets)
    box, n = _check_grid(box, n_grid)
    excess, counts = _flux_excess_raw(a, code, p0, p1, p2, d, box, n)
    return (excess, counts) if return_counts else excess


def flux_excess_distribution(jacobian, subhalo, r_eff_values, n_angles=36, *, theta_e=None,
                             definition="paper", box=10.0, n_grid=400):
    """Flux excess on concentric ellipses ``r_eff`` (data of the paper's Fig. 8).

    Parameters
    ----------
    jacobian, subhalo, box, n_grid
        As in :func:`micro_images`.
    r_eff_values : array_like
        Values of ``r_eff`` (>= 0).
    n_angles : int
        Angles per ellipse, ``360 k / n_angles`` deg (see
        :func:`offsets_on_ellipse`).
    theta_e : `~astropy.units.Quantity`, optional
        Einstein radius defining ``r_eff``; default
        :func:`subhalo_einstein_radius` (the paper uses the point-mass
        Einstein radius of M200, :func:`lensdual.abundance.einstein_radius`).
    definition : {"paper", "caustic"}
        Definition of ``r_eff`` (see :func:`effective_radius_ellipse`).

    Returns
    -------
    table : `~astropy.table.QTable`
        ``r_eff``, ``angle`` (deg), ``x_offset``, ``y_offset`` (arcsec),
        ``flux_excess``, ``n_images``; ``meta['theta_e']``.

    Examples
    --------
    A point mass in an isotropic macro field (see :func:`micro_images`) on
    three ellipses, here circles, of four angles each:

    >>> import numpy as np
    >>> from lensdual.sensitivity import flux_excess_distribution
    >>> tab = flux_excess_distribution(0.5 * np.eye(2), {"theta_E": 0.02}, [0.5, 1.0, 2.0],
    ...                                n_angles=4, n_grid=200)
    >>> len(tab), tab["angle"][:4].value.tolist()
    (12, [0.0, 90.0, 180.0, 270.0])
    >>> np.round(tab["flux_excess"][::4], 3).tolist()
    [2.959, 1.667, 1.155]
    """
    a = _as_jacobian(jacobian)
    code, p0, p1, p2 = _as_subhalo(subhalo)
    te = subhalo_einstein_radius(subhalo) if theta_e is None else theta_e
    n_ang = as_int(n_angles, "n_angles", minimum=1)
    r = _as_r_eff(r_eff_values, "r_eff_values")
    ang = np.arange(n_ang) * (360.0 / n_ang) * u.deg
    d = offsets_on_ellipse(r, ang, a, te, definition=definition).to_value(u.arcsec)
    box, n = _check_grid(box, n_grid)
    excess, counts = _flux_excess_raw(a, code, p0, p1, p2, np.ascontiguousarray(d), box, n)
    t = QTable({
        "r_eff": np.repeat(r, n_ang),
        "angle": np.tile(ang.value, r.size) * u.deg,
        "x_offset": d[:, 0] * u.arcsec,
        "y_offset": d[:, 1] * u.arcsec,
        "flux_excess": excess,
        "n_images": counts,
    })
    t.meta["theta_e"] = u.Quantity(te, u.arcsec)
    t.meta["definition"] = definition
    return t

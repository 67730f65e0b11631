"""Sub-halo sensitivity: flux excess of a macro image perturbed by a sub-halo (paper Sect. 5.2.3).

Local model: a point source whose macro image sits at ``theta0`` where the
macro lens is locally linear, ``beta - beta0 = A0 (theta - theta0)`` with
``A0 = d beta / d theta`` (valid because a sub-halo's Einstein radius,
0.005-0.05 arcsec, is tiny compared with the scale on which the macro field
varies). A circular sub-halo at image-plane offset ``d`` from the macro
image adds ``alpha_sub(theta - theta0 - d)``; the images of the source solve

    0 = A0 (theta - theta0) - alpha_sub(theta - theta0 - d).

Definitions
-----------
Unit ellipse and ``r_eff``
    With ``A0 = sum_i lambda_i e_i e_i^T`` (eigen-decomposition of its
    symmetric part), the unit ellipse is the image-plane set of offsets
    ``{d : sum_i |lambda_i| (d . e_i)^2 = (2 theta_E)^2}``, semi-axes
    ``a_i = 2 theta_E / sqrt(|lambda_i|)`` along ``e_i``, and
    ``r_eff(d) = sqrt(sum_i |lambda_i| (d . e_i)^2) / (2 theta_E)``.
    ``theta_E / sqrt(|lambda_i|)`` is the isolated Einstein radius mapped
    through the macro deformation (where the sub-halo's shear
    ``theta_E^2 / r^2`` equals ``|lambda_i|``: the sub-halo's critical curve
    crosses the eigen-axis there); for a point mass at a saddle-point
    macro image the caustic, mapped back to offsets, has a cusp exactly on
    this ellipse on the axis of the negative eigenvalue and lies at
    ``0.98 <= r_eff <= 1.15`` for the SMACS0723 analogue's L2 Jacobian.
Flux excess
    ``sum_i |mu_i| / |mu_0|`` over all micro-images, ``mu_0 = 1 / det A0``;
    1 without sub-halo.
"""

import math

import numpy as np
from astropy import units as u
from astropy.table import QTable

from . import _sensitivity_kernels as _k
from ._validation import as_int, as_real

__all__ = [
    "effective_radius_ellipse",
    "effective_radius",
    "offsets_on_ellipse",
    "subhalo_einstein_radius",
    "micro_images",
    "flux_excess",
    "flux_excess_distribution",
    "plot_flux_excess_violin",
    "smacs0723_reference",
    "detection_snr_map",
]

_MAX_IMAGES = 16


# ----------------------------------------------------------------------------- inputs


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


def _as_subhalo(subhalo):
    """-> (profile code, p0, p1, p2) from a LensComponent or lenstronomy kwargs."""
    from .simulation.halos import LensComponent

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
            rs, ars, rt = (float(kw[k]) for k in ("Rs", "alpha_Rs", "r_trunc"))
        except KeyError as err:
            raise ValueError(f"subhalo TNFW kwargs lack {err.args[0]!r}") from None
        for k, v in (("Rs", rs), ("alpha_Rs", ars), ("r_trunc", rt)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"subhalo {k} must be finite and > 0, got {v}")
        return _k.PROFILE_TNFW, rs, _k.tnfw_rho0(rs, ars), rt
    if profile == "POINT_MASS":
        te = float(kw["theta_E"])
        if not (math.isfinite(te) and te > 0):
            raise ValueError(f"subhalo theta_E must be finite and > 0, got {te}")
        return _k.PROFILE_POINT, te, 0.0, 0.0
    raise ValueError(f"subhalo profile must be 'TNFW' or 'POINT_MASS', got {profile!r}")


def subhalo_einstein_radius(subhalo):
    """Point-mass Einstein radius of a sub-halo's total projected mass.

    ``theta_E = sqrt(r alpha(r))`` for ``r -> infinity`` (``1e4 r_trunc``
    for a TNFW), or ``theta_E`` of a point mass.

    Parameters
    ----------
    subhalo : `~lensdual.simulation.LensComponent` or dict
        ``TNFW`` (lenstronomy kwargs ``Rs, alpha_Rs, r_trunc``) or
        ``POINT_MASS`` (``theta_E``).

    Returns
    -------
    theta_E : `~astropy.units.Quantity`
        arcsec.
    """
    code, p0, p1, p2 = _as_subhalo(subhalo)
    return _te(code, p0, p1, p2) * u.arcsec


# ----------------------------------------------------------------------------- r_eff


def effective_radius_ellipse(jacobian, theta_e):
    """The unit ellipse ``r_eff = 1`` of a sub-halo at a macro image (paper Fig. 7).

    Parameters
    ----------
    jacobian : array_like, shape (2, 2)
        Macro Jacobian ``A0 = d beta / d theta`` at the image (its symmetric
        part is used).
    theta_e : `~astropy.units.Quantity`
        Isolated Einstein radius of the sub-halo.

    Returns
    -------
    semi_axes : `~astropy.units.Quantity`, shape (2,)
        ``2 theta_E / sqrt(|lambda_i|)`` along the eigenvectors of ``A0``, in
        the order of ascending eigenvalue.
    orientation : `~astropy.units.Quantity`
        Angle of the first axis from the x axis (deg, in (-90, 90]).

    Notes
    -----
    See the module docstring; ``r_eff(d) = sqrt(sum |lambda_i| (d.e_i)^2) / (2 theta_E)``.
    """
    a = _as_jacobian(jacobian)
    te = _as_theta_e(theta_e)
    lam, vec = _eig(a)
    axes = 2.0 * te / np.sqrt(np.abs(lam))
    ang = math.degrees(math.atan2(vec[1, 0], vec[0, 0]))
    if ang <= -90:
        ang += 180
    elif ang > 90:
        ang -= 180
    return axes * u.arcsec, ang * u.deg


def effective_radius(offsets, jacobian, theta_e):
    """``r_eff`` of image-plane sub-halo offsets (see :func:`effective_radius_ellipse`).

    Parameters
    ----------
    offsets : `~astropy.units.Quantity`, shape (N, 2) or (2,)
        Sub-halo centre minus macro image position.
    jacobian : array_like, shape (2, 2)
    theta_e : `~astropy.units.Quantity`

    Returns
    -------
    r_eff : `~numpy.ndarray`, shape (N,)

    Examples
    --------
    >>> import numpy as np
    >>> import astropy.units as u
    >>> from lensdual.sensitivity import effective_radius
    >>> A0 = np.diag([-0.25, 0.64])
    >>> effective_radius([[0.08, 0.0], [0.0, 0.05]] * u.arcsec, A0, 0.02 * u.arcsec)
    array([1., 1.])
    """
    d = _as_offsets(offsets)
    a = _as_jacobian(jacobian)
    te = _as_theta_e(theta_e)
    lam, vec = _eig(a)
    c = d @ vec
    return np.sqrt((np.abs(lam) * c**2).sum(axis=1)) / (2.0 * te)


def offsets_on_ellipse(r_eff, angles, jacobian, theta_e):
    """Offsets ``d`` with the given ``r_eff`` at parametric ``angles`` on the ellipse.

    ``d = r_eff (a_1 cos(phi) e_1 + a_2 sin(phi) e_2)``.

    Returns
    -------
    offsets : `~astropy.units.Quantity`, shape (len(r_eff) * len(angles), 2)
        r_eff varies slowest.
    """
    r = np.atleast_1d(np.asarray(r_eff, dtype=np.float64))
    if r.size == 0 or r.ndim != 1:
        raise ValueError(f"r_eff must be a non-empty 1-d array, got shape {r.shape}")
    if not (np.isfinite(r) & (r >= 0)).all():
        raise ValueError("r_eff must be finite and >= 0")
    phi = np.atleast_1d(_as_angle_value(angles, "angles") * (math.pi / 180 / 3600))
    a = _as_jacobian(jacobian)
    te = _as_theta_e(theta_e)
    lam, vec = _eig(a)
    axes = 2.0 * te / np.sqrt(np.abs(lam))
    local = np.stack([axes[0] * np.cos(phi), axes[1] * np.sin(phi)], axis=1)  # (A, 2)
    base = local @ vec.T
    return (r[:, None, None] * base[None, :, :]).reshape(-1, 2) * u.arcsec


# ----------------------------------------------------------------------------- images


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


def _check_grid(box, n_grid):
    box = as_real(box, "box", minimum=0.0, inclusive=False)
    n = as_int(n_grid, "n_grid", minimum=8)
    return box, n


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
    A point mass in a uniform field ``A0 = 0.5 I`` at ``r_eff = 0.5``
    (impact parameter u = 1 of the rescaled point lens):

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
                             box=10.0, n_grid=400):
    """Flux excess on concentric ellipses ``r_eff`` (data of the paper's Fig. 8).

    Parameters
    ----------
    jacobian, subhalo, box, n_grid
        As in :func:`micro_images`.
    r_eff_values : array_like
        Values of ``r_eff`` (>= 0).
    n_angles : int
        Parametric angles per ellipse, ``360 k / n_angles`` deg.
    theta_e : `~astropy.units.Quantity`, optional
        Einstein radius defining ``r_eff``; default
        :func:`subhalo_einstein_radius`.

    Returns
    -------
    table : `~astropy.table.QTable`
        ``r_eff``, ``angle`` (deg), ``x_offset``, ``y_offset`` (arcsec),
        ``flux_excess``, ``n_images``; ``meta['theta_e']``.
    """
    a = _as_jacobian(jacobian)
    code, p0, p1, p2 = _as_subhalo(subhalo)
    te = subhalo_einstein_radius(subhalo) if theta_e is None else theta_e
    n_ang = as_int(n_angles, "n_angles", minimum=1)
    r = np.atleast_1d(np.asarray(r_eff_values, dtype=np.float64))
    if r.ndim != 1 or r.size == 0:
        raise ValueError(f"r_eff_values must be a non-empty 1-d array, got shape {r.shape}")
    ang = np.arange(n_ang) * (360.0 / n_ang) * u.deg
    d = offsets_on_ellipse(r, ang, a, te).to_value(u.arcsec)
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
    return t


def plot_flux_excess_violin(table, ax=None, mu_size_band=None):
    """Violins of the flux excess per ``r_eff`` (paper Fig. 8).

    Parameters
    ----------
    table : `~astropy.table.QTable`
        From :func:`flux_excess_distribution`.
    ax : `matplotlib.axes.Axes`, optional
    mu_size_band : (float, float), optional
        Lower and upper edge of a hatched reference band (e.g. the 16-84 %
        range of ``mu_size``).

    Returns
    -------
    ax : `matplotlib.axes.Axes`
    """
    import matplotlib.pyplot as plt

    for col in ("r_eff", "flux_excess"):
        if col not in getattr(table, "colnames", ()):
            raise ValueError(f"table must have column {col!r} (from flux_excess_distribution)")
    if ax is None:
        _, ax = plt.subplots()
    r = np.asarray(table["r_eff"], dtype=float)
    fe = np.asarray(table["flux_excess"], dtype=float)
    levels = np.unique(r)
    data = [fe[r == lv] for lv in levels]
    width = 0.8 * (np.min(np.diff(levels)) if levels.size > 1 else 1.0)
    ax.violinplot(data, positions=levels, widths=width, showmedians=True)
    if mu_size_band is not None:
        lo, hi = (float(v) for v in mu_size_band)
        ax.axhspan(lo, hi, hatch="//", fill=False, color="0.4", lw=0)
    ax.axhline(1.0, color="0.5", ls=":")
    ax.set_yscale("log")
    ax.set_xlabel(r"$r_{\rm eff}$")
    ax.set_ylabel("flux excess")
    return ax


# ----------------------------------------------------------------------------- SNR map


def smacs0723_reference(*, seed=0, source=0, sigma_pos=0.06 * u.arcsec, n_bootstrap=500,
                        bootstrap_seed=0):
    """Macro Jacobian and size-magnification noise of the SMACS0723 analogue.

    The macro image is the L2 image of source ``source`` of
    ``smacs0723_analog(seed=seed)``; the noise is the relative Quad-Jacobian
    bootstrap error of ``mu_size`` of that pair at ``sigma_pos``.

    Returns
    -------
    ref : dict
        ``jacobian`` ((2, 2) ``d beta / d theta`` at the L2 image),
        ``mu_macro`` (signed ``1 / det``), ``mu_size``, ``mu_size_err``,
        ``sigma_lnsize`` (``mu_size_err / mu_size``), ``position`` (the L2
        image, arcsec).
    """
    from .estimators import size_magnification
    from .simulation.scenarios import smacs0723_analog

    system = smacs0723_analog(seed=seed)
    p = system.constellation()
    k = as_int(source, "source", minimum=0)
    rows = np.flatnonzero(np.asarray(p["source"]) == k)
    if rows.size == 0:
        raise ValueError(f"source {k} has no image pair in the SMACS0723 analogue")
    t1 = u.Quantity([p["x1"], p["y1"]]).T
    t2 = u.Quantity([p["x2"], p["y2"]]).T
    pos = t2[rows[0]][None, :]
    jac = system.jacobian(pos)[0]
    size = size_magnification(t1, t2, "quad", sigma_pos=sigma_pos, n_bootstrap=n_bootstrap,
                              seed=bootstrap_seed)
    mu = float(size["mu_size"][rows[0]])
    err = float(size["mu_size_err"][rows[0]])
    return {"jacobian": jac, "mu_macro": 1.0 / float(np.linalg.det(jac)), "mu_size": mu,
            "mu_size_err": err, "sigma_lnsize": err / mu, "position": pos[0]}


def _snr_chunk(args):
    """Percentiles of the SNR over angles for a chunk of masses (picklable)."""
    (masses, conc, a, r_eff, n_angles, sigma, percentiles, zl, zs, cosmology, box, n) = args
    from .abundance import einstein_radius
    from .simulation.halos import mass_concentration, tnfw_halo

    ang = np.arange(n_angles) * (360.0 / n_angles) * u.deg
    out = []
    for m in masses:
        mq = m * u.Msun
        c = mass_concentration(mq) * (1.0 if conc == "mcr" else conc)
        sub = tnfw_halo(mq, c, z_lens=zl, z_source=zs, cosmology=cosmology)
        code, p0, p1, p2 = _as_subhalo(sub)
        te = einstein_radius(mq, zl, zs, cosmology)
        d = np.ascontiguousarray(offsets_on_ellipse(r_eff, ang, a, te).to_value(u.arcsec))
        fe, cnt = _flux_excess_raw(a, code, p0, p1, p2, d, box, n)
        snr = (np.abs(np.log(fe)) / sigma).reshape(r_eff.size, n_angles)
        fe = fe.reshape(r_eff.size, n_angles)
        out.append((float(te.value), c, np.percentile(snr, percentiles, axis=1).T,
                    np.median(fe, axis=1), cnt.reshape(r_eff.size, n_angles).max(axis=1)))
    return out


def detection_snr_map(masses, r_eff, *, jacobian, sigma_lnsize, concentration="mcr",
                      percentiles=(50, 68, 95), n_angles=36, z_lens=0.39, z_source=2.2,
                      cosmology=None, box=10.0, n_grid=400, executor=None, chunk_size=1):
    """Sub-halo detection SNR over masses and ``r_eff`` (paper Fig. 9).

    For each mass (circular TNFW, ``r_trunc = 30 Rs``) and each ``r_eff``
    (normalised to the point-mass Einstein radius of M200, as in the paper),
    the sub-halo is placed at ``n_angles`` parametric angles on the ellipse
    and the signal is the duality ratio ``mu_flux / mu_size``, i.e. the flux
    excess ``f`` (sub-halo on the L1 image) or ``1 / f`` (on L2); either way
    ``SNR = |ln f| / sigma_lnsize``. The requested percentiles of the SNR
    over the angles are returned.

    Parameters
    ----------
    masses : `~astropy.units.Quantity`
        M200 of the sub-haloes (1-d).
    r_eff : array_like
        Non-empty 1-d ``r_eff`` values (>= 0).
    jacobian : array_like, shape (2, 2)
        Macro ``d beta / d theta`` at the perturbed image (e.g.
        ``smacs0723_reference()["jacobian"]``).
    sigma_lnsize : float
        Relative error of the size magnification (> 0), e.g.
        ``smacs0723_reference()["sigma_lnsize"]``.
    concentration : "mcr" or float
        ``"mcr"``: the mass-concentration relation; a number multiplies it
        (5 for the paper's over-concentrated row).
    percentiles : sequence of float
        Percentiles over angles (default 50, 68, 95).
    n_angles : int
        Angles per ellipse.
    z_lens, z_source, cosmology
        Of the sub-halo and the source.
    box, n_grid
        Image search, see :func:`micro_images`.
    executor : `concurrent.futures.Executor` or dask ``Client``, optional
        Anything with ``.map(fn, iterable)`` (a dask Client's futures are
        gathered with ``.gather``). None runs serially. Results are identical.
    chunk_size : int
        Masses per task.

    Returns
    -------
    table : `~astropy.table.QTable`
        One row per (mass, r_eff): ``mass``, ``concentration``, ``theta_e``,
        ``r_eff``, ``snr_p<q>`` per percentile, ``flux_excess_median``,
        ``max_images``.
    """
    from ._validation import as_cosmology, as_mass, as_redshifts

    m = np.atleast_1d(as_mass(masses, "masses").value)
    if m.ndim != 1 or m.size == 0:
        raise ValueError(f"masses must be a non-empty 1-d Quantity, got shape {m.shape}")
    r = np.atleast_1d(np.asarray(r_eff, dtype=np.float64))
    if r.ndim != 1 or r.size == 0:
        raise ValueError(f"r_eff must be a non-empty 1-d array, got shape {r.shape}")
    if not (np.isfinite(r) & (r >= 0)).all():
        raise ValueError("r_eff must be finite and >= 0")
    a = _as_jacobian(jacobian)
    sigma = as_real(sigma_lnsize, "sigma_lnsize", minimum=0.0, inclusive=False)
    if isinstance(concentration, str):
        if concentration != "mcr":
            raise ValueError(
                f"concentration must be 'mcr' or a positive factor, got {concentration!r}"
            )
        conc = "mcr"
    else:
        conc = as_real(concentration, "concentration", minimum=0.0, inclusive=False)
    q = np.atleast_1d(np.asarray(percentiles, dtype=np.float64))
    if q.ndim != 1 or q.size == 0 or not ((q >= 0) & (q <= 100)).all():
        raise ValueError(f"percentiles must be a non-empty sequence in [0, 100], got {percentiles}")
    n_ang = as_int(n_angles, "n_angles", minimum=1)
    zl, zs = as_redshifts(z_lens, z_source)
    cosmology = as_cosmology(cosmology)
    box, n = _check_grid(box, n_grid)
    cs = as_int(chunk_size, "chunk_size", minimum=1)
    tasks = [(m[i:i + cs], conc, a, r, n_ang, sigma, q, zl, zs, cosmology, box, n)
             for i in range(0, m.size, cs)]
    if executor is None:
        results = [_snr_chunk(t) for t in tasks]
    elif hasattr(executor, "gather") and hasattr(executor, "map"):  # dask.distributed Client
        results = executor.gather(executor.map(_snr_chunk, tasks, pure=False))
    elif hasattr(executor, "map"):
        results = list(executor.map(_snr_chunk, tasks))
    else:
        raise TypeError("executor must be None, a concurrent.futures.Executor or a dask Client, "
                        f"got {type(executor).__name__}")
    rows = [row for chunk in results for row in chunk]
    nr = r.size
    cols = {
        "mass": np.repeat(m, nr) * u.Msun,
        "concentration": np.repeat([row[1] for row in rows], nr),
        "theta_e": np.repeat([row[0] for row in rows], nr) * u.arcsec,
        "r_eff": np.tile(r, m.size),
    }
    snr = np.vstack([row[2] for row in rows])
    for j, qq in enumerate(q):
        cols[f"snr_p{qq:g}"] = snr[:, j]
    cols["flux_excess_median"] = np.concatenate([row[3] for row in rows])
    cols["max_images"] = np.concatenate([row[4] for row in rows])
    t = QTable(cols)
    t.meta.update({"sigma_lnsize": sigma, "n_angles": n_ang, "percentiles": q.tolist(),
                   "concentration": conc})
    return t

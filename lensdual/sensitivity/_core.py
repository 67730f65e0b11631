"""The implementation of :mod:`lensdual.sensitivity` (see the package docstring)."""

import math

import numpy as np
from astropy import units as u
from astropy.table import QTable

from .._pairs_table import positions
from .._parallel import check_client, run_tasks
from .._validation import as_int, as_real
from . import _kernels as _k

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
    "plot_detection_snr_map",
]

_MAX_IMAGES = 16
_DEFINITIONS = ("paper", "caustic")
_PLANES = ("image", "source")
_SIGNALS = ("ratio", "log", "inverse")


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
    """
    code, p0, p1, p2 = _as_subhalo(subhalo)
    return _te(code, p0, p1, p2) * u.arcsec


# ----------------------------------------------------------------------------- r_eff


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
    """
    r = _as_r_eff(r_eff)
    phi = np.atleast_1d(_as_angle_value(angles, "angles") * (math.pi / 180 / 3600))
    a = _as_jacobian(jacobian)
    te = _as_theta_e(theta_e)
    _choice(definition, "definition", _DEFINITIONS)
    base = np.stack([np.cos(phi), np.sin(phi)], axis=1) @ _unit_map(a, te, definition).T
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


def smacs0723_reference(*, seed=0, source=0, image=2, sigma_pos=0.06 * u.arcsec,
                        n_bootstrap=500, bootstrap_seed=0, method="adaptive"):
    """Macro Jacobian and size-magnification noise of the SMACS0723 analogue.

    The macro image is the image on arc L``image`` of source ``source`` of
    ``smacs0723_analog(seed=seed)`` (L2: a saddle point, eigenvalues of
    ``d beta / d theta`` -0.635 and 0.223 for the defaults; L1: a maximum,
    -1.14 and -0.28, the analogue's fold being radial); the noise is the
    relative Quad-Jacobian bootstrap error of ``mu_size`` of that pair at
    positional error ``sigma_pos``.

    Parameters
    ----------
    seed : int
        Seed of the analogue's source positions.
    source : int
        Which source's pair.
    image : {1, 2}
        Arc of the perturbed image.
    sigma_pos : `~astropy.units.Quantity`
        Positional error of the bootstrap (the paper's 0.06 arcsec).
    n_bootstrap, bootstrap_seed
        Of :func:`lensdual.estimators.size_magnification` (bootstrap
        methods only).
    method : str
        Size-magnification estimator (default ``"adaptive"``).

    Returns
    -------
    ref : dict
        ``jacobian`` ((2, 2) ``d beta / d theta`` at the image),
        ``mu_macro`` (signed ``1 / det``), ``mu_size``, ``mu_size_err``,
        ``sigma_rel`` (the relative error: the error of ``ln mu_size`` for
        ``"adaptive"``, ``mu_size_err / mu_size`` for the bootstrap methods),
        ``method``, ``position`` (the image, arcsec), ``image``.

    Notes
    -----
    The analogue's constellation is compact (the images of the 16 sources
    spread over about 0.06 x 0.2 arcsec), so the calibrated ``sigma_rel``
    is 1.09 at 0.06 arcsec (Quad bootstrap: 1.0) and 0.09 at 0.005 arcsec
    (Quad: 0.12); the paper quotes a
    recovery of ``mu_size`` to about 10 % for its analogue and
    ``1.04 +- 0.09`` for the real pair 1 at 0.06 arcsec.
    """
    from ..estimators import size_magnification
    from ..simulation.scenarios import smacs0723_analog

    k = as_int(source, "source", minimum=0)
    img = as_int(image, "image", minimum=1)
    if img not in (1, 2):
        raise ValueError(f"image must be 1 or 2, got {image}")
    system = smacs0723_analog(seed=seed)
    p = system.constellation()
    rows = np.flatnonzero(np.asarray(p["source"]) == k)
    if rows.size == 0:
        raise ValueError(f"source {k} has no image pair in the SMACS0723 analogue")
    t1, t2 = positions(p)
    pos = (t1 if img == 1 else t2)[rows[0]][None, :]
    jac = system.jacobian(pos)[0]
    size = size_magnification(t1, t2, method, sigma_pos=sigma_pos, n_bootstrap=n_bootstrap,
                              seed=bootstrap_seed)
    mu = float(size["mu_size"][rows[0]])
    err = float(size["mu_size_err"][rows[0]])
    ln_err = float(size["ln_mu_size_err"][rows[0]])
    return {"jacobian": jac, "mu_macro": 1.0 / float(np.linalg.det(jac)), "mu_size": mu,
            "mu_size_err": err, "sigma_rel": ln_err if method == "adaptive" else err / mu,
            "method": method, "position": pos[0], "image": img}


def _signal(fe, signal):
    if signal == "ratio":
        return np.abs(fe - 1.0)
    if signal == "log":
        return np.abs(np.log(fe))
    return np.abs(1.0 / fe - 1.0)


def _snr_chunk(task):
    """SNR statistics over angles for a chunk of masses (module level: picklable).

    The angles of mass number ``i`` (its index in the whole grid) depend on
    ``(seed, i)`` only, so a chunk gives the same numbers whatever the
    chunking and wherever it runs.
    """
    (index, masses, conc, a, r, n_ang, sigma, q, signal, definition, seed, zl, zs, cosmology,
     box, n) = task
    from ..abundance import einstein_radius
    from ..simulation.halos import mass_concentration, tnfw_halo

    k = np.arange(n_ang)
    out = []
    for i, m in zip(index, masses, strict=True):
        mq = m * u.Msun
        c = mass_concentration(mq) * (1.0 if conc == "mcr" else conc)
        sub = tnfw_halo(mq, c, z_lens=zl, z_source=zs, cosmology=cosmology)
        code, p0, p1, p2 = _as_subhalo(sub)
        te = float(einstein_radius(mq, zl, zs, cosmology).to_value(u.arcsec))
        if seed is None:
            phase = np.zeros(r.size)
        else:
            phase = np.random.default_rng([seed, int(i)]).random(r.size)
        phi = (k[None, :] + phase[:, None]) * (2.0 * math.pi / n_ang)
        unit = np.stack([np.cos(phi), np.sin(phi)], axis=-1) @ _unit_map(a, te, definition).T
        d = np.ascontiguousarray((r[:, None, None] * unit).reshape(-1, 2))
        fe, cnt = _flux_excess_raw(a, code, p0, p1, p2, d, box, n)
        fe = fe.reshape(r.size, n_ang)
        snr = _signal(fe, signal) / sigma
        out.append((te, c, snr.mean(axis=1), np.percentile(snr, q, axis=1).T,
                    np.median(fe, axis=1), cnt.reshape(r.size, n_ang).max(axis=1)))
    return out


def _check_pool(client, executor):
    if client is not None and executor is not None:
        raise ValueError("give client or executor (its alias), not both")
    return check_client(client if client is not None else executor)


def detection_snr_map(masses, r_eff, *, jacobian=None, sigma_rel=None, sigma_pos=None,
                      concentration="mcr", percentiles=(50, 68, 95), n_angles=36,
                      signal="ratio", definition="paper", seed=None, z_lens=0.39,
                      z_source=2.2, cosmology=None, box=10.0, n_grid=400, client=None,
                      executor=None, chunk_size=1):
    """Sub-halo detection SNR over masses and ``r_eff`` (paper Fig. 9).

    For each mass (circular TNFW, ``r_trunc = 30 Rs``) and each ``r_eff``
    (normalised to the point-mass Einstein radius of M200, as in the paper),
    the sub-halo is placed at ``n_angles`` angles around the macro image and
    the flux excess ``f`` of the image (all micro-images summed) is
    computed; the SNR is the signal over ``sigma_rel``, the relative error
    of ``mu_size``. Returned are the mean and the requested percentiles of
    the SNR over the angles.

    Parameters
    ----------
    masses : `~astropy.units.Quantity`
        M200 of the sub-haloes (non-empty, 1-d, > 0).
    r_eff : array_like
        Non-empty 1-d ``r_eff`` values (>= 0).
    jacobian : array_like, shape (2, 2), optional
        Macro ``d beta / d theta`` at the perturbed image. Default: the L2
        image of :func:`smacs0723_reference` (a saddle point).
    sigma_rel : float, optional
        Relative error of ``mu_size`` (> 0). Required with ``jacobian``;
        with ``jacobian=None`` it defaults to the calibrated error (adaptive
        estimator, truncation error included) of :func:`smacs0723_reference`
        at ``sigma_pos``.
    sigma_pos : `~astropy.units.Quantity`, optional
        Positional error of that reference (default 0.06 arcsec); only with
        ``jacobian=None`` and ``sigma_rel=None``.
    concentration : "mcr" or float
        ``"mcr"``: the mass-concentration relation; a number multiplies it
        (5 for the paper's second row of Fig. 9).
    percentiles : sequence of float
        Percentiles over angles (default 50, 68, 95), in [0, 100].
    n_angles : int
        Angles per ``r_eff``, ``360 (k + phase) / n_angles`` deg.
    signal : {"ratio", "log", "inverse"}
        ``"ratio"`` (the paper's): ``|mu_flux / mu_size - 1|`` with
        ``mu_flux / mu_size = f``, the sub-halo on the image in the
        numerator of the flux ratio; ``"inverse"``: ``|1 / f - 1|``, the
        sub-halo on the other image; ``"log"``: ``|ln f|``, either.
    definition : {"paper", "caustic"}
        Definition of ``r_eff`` (see :func:`effective_radius_ellipse`).
    seed : int or `numpy.random.Generator`, optional
        None: the same angles ``360 k / n_angles`` for every cell (phase 0).
        An int: a random phase per (mass, ``r_eff``) cell, drawn from
        ``numpy.random.default_rng([seed, i])`` for the ``i``-th mass, so
        that the result does not depend on the chunking or the executor. A
        Generator gives that int (one draw).
    z_lens, z_source, cosmology
        Of the sub-halo and the source (defaults: the paper's 0.39, 2.2 and
        flat LCDM with H0 = 70, Om0 = 0.3).
    box, n_grid
        Image search, see :func:`micro_images`.
    client : `dask.distributed.Client` or `concurrent.futures.Executor`, optional
        Where to run the chunks: a dask Client (``client.map`` then
        ``client.gather``) or anything with an Executor-like ``map``. None
        runs serially. The result is identical in every case.
    executor : optional
        Alias of ``client`` (give one of them).
    chunk_size : int
        Masses per task (>= 1).

    Returns
    -------
    table : `~astropy.table.QTable`
        One row per (mass, r_eff), r_eff varying fastest: ``mass``,
        ``concentration``, ``theta_e``, ``r_eff``, ``snr_mean``,
        ``snr_p<q>`` per percentile, ``flux_excess_median``, ``max_images``
        (most micro-images over the angles); ``meta`` holds the settings,
        the ``jacobian`` and ``sigma_rel``.

    Raises
    ------
    TypeError
        ``masses`` not a mass Quantity; ``client`` without ``map``.
    ValueError
        Empty or negative grids, ``percentiles`` outside [0, 100], a bad
        option, ``z_source <= z_lens``, or ``jacobian`` without
        ``sigma_rel``.

    Examples
    --------
    >>> import numpy as np
    >>> import astropy.units as u
    >>> from lensdual.sensitivity import detection_snr_map
    >>> A0 = np.array([[-0.6163, 0.1266], [0.1266, 0.2037]])  # SMACS0723 analogue, L2
    >>> t = detection_snr_map([1e8] * u.Msun, [0.5, 2.0], jacobian=A0, sigma_rel=0.1,
    ...                       concentration=5.0, n_angles=12, n_grid=200)
    >>> print(np.round(t["snr_p95"], 1))
    [24.4  4.8]
    """
    from .._validation import as_angle_scalar, as_cosmology, as_mass, as_redshifts

    m = np.atleast_1d(as_mass(masses, "masses").value)
    if m.ndim != 1 or m.size == 0:
        raise ValueError(f"masses must be a non-empty 1-d Quantity, got shape {m.shape}")
    r = _as_r_eff(r_eff)
    if isinstance(concentration, str):
        if concentration != "mcr":
            raise ValueError(
                f"concentration must be 'mcr' or a positive factor, got {concentration!r}"
            )
        conc = "mcr"
    else:
        conc = as_real(concentration, "concentration", minimum=0.0, inclusive=False)
    try:
        q = np.atleast_1d(np.asarray(percentiles, dtype=np.float64))
    except (TypeError, ValueError):
        raise TypeError(f"percentiles must be real numbers, got {percentiles!r}") from None
    if q.ndim != 1 or q.size == 0 or not ((q >= 0) & (q <= 100)).all():
        raise ValueError(f"percentiles must be a non-empty sequence in [0, 100], got {percentiles}")
    n_ang = as_int(n_angles, "n_angles", minimum=1)
    _choice(signal, "signal", _SIGNALS)
    _choice(definition, "definition", _DEFINITIONS)
    if isinstance(seed, np.random.Generator):
        seed = int(seed.integers(0, 2**63 - 1))
    elif seed is not None:
        seed = as_int(seed, "seed", minimum=0)
    zl, zs = as_redshifts(z_lens, z_source)
    cosmology = as_cosmology(cosmology)
    box, n = _check_grid(box, n_grid)
    cs = as_int(chunk_size, "chunk_size", minimum=1)
    pool = _check_pool(client, executor)
    if sigma_rel is not None:
        sigma = as_real(sigma_rel, "sigma_rel", minimum=0.0, inclusive=False)
        if sigma_pos is not None:
            raise ValueError("give sigma_rel or sigma_pos, not both (sigma_pos sets the "
                             "bootstrap error that sigma_rel would replace)")
    meta = {}
    if jacobian is None:
        sp = 0.06 * u.arcsec if sigma_pos is None else sigma_pos
        as_angle_scalar(sp, "sigma_pos", allow_zero=False)
        ref = smacs0723_reference(sigma_pos=sp)
        a = ref["jacobian"]
        if sigma_rel is None:
            sigma = ref["sigma_rel"]
            meta["sigma_pos"] = sp
    else:
        a = _as_jacobian(jacobian)
        if sigma_rel is None:
            raise ValueError("sigma_rel is required with a jacobian (sigma_pos only sets the "
                             "bootstrap error of the default SMACS0723 reference)")
    _eig(a)
    tasks = [(np.arange(i, min(i + cs, m.size)), m[i:i + cs], conc, a, r, n_ang, sigma, q,
              signal, definition, seed, zl, zs, cosmology, box, n)
             for i in range(0, m.size, cs)]
    rows = [row for chunk in run_tasks(_snr_chunk, tasks, pool) for row in chunk]
    nr = r.size
    cols = {
        "mass": np.repeat(m, nr) * u.Msun,
        "concentration": np.repeat([row[1] for row in rows], nr),
        "theta_e": np.repeat([row[0] for row in rows], nr) * u.arcsec,
        "r_eff": np.tile(r, m.size),
        "snr_mean": np.concatenate([row[2] for row in rows]),
    }
    snr = np.vstack([row[3] for row in rows])
    for j, qq in enumerate(q):
        cols[f"snr_p{qq:g}"] = snr[:, j]
    cols["flux_excess_median"] = np.concatenate([row[4] for row in rows])
    cols["max_images"] = np.concatenate([row[5] for row in rows])
    t = QTable(cols)
    meta.update({"jacobian": a.tolist(), "sigma_rel": sigma, "signal": signal,
                 "definition": definition, "concentration": conc, "n_angles": n_ang,
                 "percentiles": q.tolist(), "seed": seed, "z_lens": zl, "z_source": zs})
    t.meta.update(meta)
    return t


def _edges(v, log):
    w = np.log10(v) if log else v
    if w.size == 1:
        e = np.array([w[0] - 0.5, w[0] + 0.5])
    else:
        mid = 0.5 * (w[1:] + w[:-1])
        e = np.concatenate([[2 * w[0] - mid[0]], mid, [2 * w[-1] - mid[-1]]])
    return 10**e if log else e


def plot_detection_snr_map(table, *, columns=None, axes=None, vmin=0.3, vmax=100.0,
                           levels=(3, 5, 10), cmap="viridis"):
    """SNR maps over ``r_eff`` (x) and mass (y), one panel per column (paper Fig. 9).

    Parameters
    ----------
    table : `~astropy.table.QTable`
        From :func:`detection_snr_map` (one concentration model).
    columns : sequence of str, optional
        SNR columns to show; default every ``snr_p*`` column.
    axes : sequence of `matplotlib.axes.Axes`, optional
        One per column; default a new row of panels.
    vmin, vmax : float
        Limits of the logarithmic colour scale.
    levels : sequence of float
        SNR contour levels (white lines); the dashed line is ``r_eff = 1``.
    cmap : str
        Colour map.

    Returns
    -------
    axes : list of `matplotlib.axes.Axes`
    mesh : `matplotlib.collections.QuadMesh`
        Of the last panel (for a colour bar).
    """
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    names = getattr(table, "colnames", ())
    for col in ("mass", "r_eff"):
        if col not in names:
            raise ValueError(f"table must have column {col!r} (from detection_snr_map)")
    if columns is None:
        columns = [c for c in names if c.startswith("snr_p")]
    columns = list(columns)
    if not columns or any(c not in names for c in columns):
        raise ValueError(f"columns must name SNR columns of the table, got {columns}")
    mass = u.Quantity(table["mass"], u.Msun).value
    r = np.asarray(table["r_eff"], dtype=float)
    mu, ru = np.unique(mass), np.unique(r)
    if mu.size * ru.size != len(table):
        raise ValueError("table must hold one row per (mass, r_eff) pair")
    im, ir = np.searchsorted(mu, mass), np.searchsorted(ru, r)
    if axes is None:
        _, axes = plt.subplots(1, len(columns), figsize=(4 * len(columns), 3.4),
                               sharey=True, squeeze=False)
        axes = axes[0]
    axes = list(np.atleast_1d(axes))
    if len(axes) != len(columns):
        raise ValueError(f"need one axes per column: {len(columns)} columns, {len(axes)} axes")
    xe, ye = _edges(ru, False), _edges(mu, True)
    mesh = None
    for ax, col in zip(axes, columns, strict=True):
        z = np.full((mu.size, ru.size), np.nan)
        z[im, ir] = np.asarray(table[col], dtype=float)
        mesh = ax.pcolormesh(xe, ye, np.clip(z, vmin, vmax), norm=LogNorm(vmin, vmax),
                             cmap=cmap, shading="flat")
        if levels and ru.size > 1 and mu.size > 1:
            cs = ax.contour(ru, mu, z, levels=sorted(levels), colors="w", linewidths=0.8)
            ax.clabel(cs, fmt="%g", fontsize=7)
        ax.axvline(1.0, color="w", ls="--", lw=0.8)
        ax.set_yscale("log")
        ax.set_xlabel(r"$r_{\rm eff}$")
        ax.set_title(col.replace("snr_p", "SNR, ").replace("snr_mean", "mean SNR")
                     + ("th percentile" if col.startswith("snr_p") else ""))
    axes[0].set_ylabel(r"$M_{200}$ [$M_\odot$]")
    return axes, mesh

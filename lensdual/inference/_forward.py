"""The forward model: each pair's flux anomaly under a sub-halo population (private)."""

import math
from typing import NamedTuple

import numpy as np
from astropy import units as u
from astropy.table import QTable, Table
from astropy.utils.exceptions import AstropyDeprecationWarning
from scipy.spatial import cKDTree

from .._pairs_table import pair_bands, positions
from .._parallel import check_client, run_tasks
from .._validation import as_int, as_real
from ..sensitivity._kernels import tnfw_rho0
from . import _kernels
from ._population import SubhaloPopulation, _as_sigma_sub, _kpc2_values

__all__ = ["simulate_anomalies", "apply_population", "AnomalySimulation", "MIN_REALISATIONS"]

#: The fewest realisations :func:`simulate_anomalies` accepts: below it the
#: Monte-Carlo likelihood of a rare large anomaly is noise.
MIN_REALISATIONS = 100

_STRONG = 0.5  # haloes whose Hessian norm reaches this fraction of A's smallest singular value
# (and whose box can reach the image) are solved in full
_BOX_FACTOR = 2.0  # grid half-width in Einstein radii over sqrt(smallest |eigenvalue|)
_BOX_CAP = 20.0  # ... and at most this many Einstein radii
_N_GRID = 32  # grid cells per side of a halo's box
_MAX_IMAGES = 32
_MAX_RATIO_PULL = 3.0  # median |pull| of the lens's magnification ratios that refuses a lens
_LOS_CHUNK = 100  # realisations of line-of-sight haloes drawn at once
_LOS_STREAM = 1 << 30  # spawn-key word of the line-of-sight haloes' random stream


class AnomalySimulation(NamedTuple):
    """Forward-modelled flux anomalies of every pair of one constellation.

    Parameters
    ----------
    pair_id : ndarray of int, shape (P,)
    sigma_sub : `~astropy.units.Quantity`, shape (S,)
        The abundance grid, kpc^-2.
    delta : ndarray, shape (P, R, S)
        ``ln(f1 / f2)``: the log flux anomaly of the flux ratio
        ``F(L1) / F(L2)`` in realisation ``r`` at abundance ``s``.
    excess1, excess2 : ndarray, shape (P, R, S)
        The flux excesses ``f`` of the L1 and L2 images.
    n_images1, n_images2 : ndarray of int, shape (P, R, S)
        Micro-images found.
    population : SubhaloPopulation
    radius : ndarray, shape (2,)
        Disc radius (arcsec) of the haloes around the L1 and L2 images.
    """

    pair_id: np.ndarray
    sigma_sub: u.Quantity
    delta: np.ndarray
    excess1: np.ndarray
    excess2: np.ndarray
    n_images1: np.ndarray
    n_images2: np.ndarray
    population: SubhaloPopulation
    radius: np.ndarray


class _ImageTask(NamedTuple):
    jac: np.ndarray  # (2, 2) d beta / d theta
    position: np.ndarray  # (2,) arcsec, lens frame
    radius: float
    sigma: np.ndarray  # (S,) kpc^-2
    n_real: int
    seed: np.random.SeedSequence
    population: SubhaloPopulation


def _as_sigma_grid(sigma_sub):
    s = np.atleast_1d(_kpc2_values(sigma_sub, "sigma_sub"))
    if s.ndim != 1 or s.size < 2:
        raise ValueError(f"sigma_sub must be a 1-D grid of at least 2 values, got shape {s.shape}")
    if not np.isfinite(s).all() or (s <= 0).any():
        raise ValueError("sigma_sub must be finite and > 0 everywhere (the prior is "
                         f"log-uniform), got {sigma_sub}")
    if (np.diff(s) <= 0).any():
        raise ValueError("sigma_sub must increase strictly (prior bounds inverted?), got "
                         f"{sigma_sub}")
    return s


def as_lens(lens, population):
    """A LensSystem at the population's redshifts (LenstoolModel: its lens_system)."""
    if hasattr(lens, "lens_system") and not hasattr(lens, "jacobian"):
        lens = lens.lens_system(population.z_source)
    if not callable(getattr(lens, "jacobian", None)):
        raise TypeError("lens must be a lensdual LensSystem or LenstoolModel, got "
                        f"{type(lens).__name__}")
    for name in ("z_lens", "z_source"):
        zl = getattr(lens, name, None)
        if zl is not None and not math.isclose(float(zl), getattr(population, name),
                                               rel_tol=0, abs_tol=1e-6):
            raise ValueError(
                f"the lens's {name} ({float(zl)}) differs from the population's "
                f"({getattr(population, name)}): build the SubhaloPopulation at the lens's "
                "redshifts (and its cosmology)")
    return lens


def _positions(pairs):
    """The pairs' positions, (N, 2) arcsec floats per arc, checked finite."""
    if not isinstance(pairs, Table):
        raise TypeError(f"pairs must be an astropy Table or QTable, got {type(pairs).__name__}")
    xy1, xy2 = (t.to_value(u.arcsec) for t in positions(pairs))
    if not (np.isfinite(xy1).all() and np.isfinite(xy2).all()):
        raise ValueError("pairs has non-finite positions")
    return xy1, xy2


def _check_lens_ratios(pairs, jac1, jac2):
    """Refuse a lens whose magnification ratios the constellation's geometry rejects.

    Where the table holds ``mu_size`` and ``ln_mu_size_err`` (a duality
    result), the lens's ``|mu(L1) / mu(L2)|`` is compared with them; a
    median |pull| above 3 says the lens (or its frame) is not this
    constellation's.
    """
    if not {"mu_size", "ln_mu_size_err"} <= set(pairs.colnames):
        return
    with np.errstate(divide="ignore", invalid="ignore"):
        ln_lens = np.log(np.abs(np.linalg.det(jac2) / np.linalg.det(jac1)))
        z = (ln_lens - np.log(np.asarray(pairs["mu_size"], dtype=float))) / np.asarray(
            pairs["ln_mu_size_err"], dtype=float)
    z = z[np.isfinite(z)]
    if z.size and np.median(np.abs(z)) > _MAX_RATIO_PULL:
        raise ValueError(
            "the smooth lens does not reproduce the constellation's magnification ratios: "
            f"median |ln(mu_lens / mu_size)| / error = {np.median(np.abs(z)):.1f} over "
            f"{z.size} pairs (positions in another frame, or another lens?)")


def _default_radius(xy):
    """Median nearest-neighbour separation of the images on one arc [arcsec]."""
    nearest = cKDTree(xy).query(xy, k=2)[1][:, 1]
    d = xy[nearest] - xy
    return float(np.median(np.hypot(d[:, 0], d[:, 1])))


def _mean_convergence(population, position, radius, sigma_sub):
    """Mean convergence at the disc's centre of the haloes drawn in the disc.

    A halo anywhere in a disc of radius ``R`` adds, on average over its
    position, its projected mass within ``R`` of its centre over the disc's
    area; the sum over the population is the number density times that
    mass, averaged over the population by quadrature (so that every draw at
    this position removes the same sheet).
    """
    r2d = float(np.hypot(*(position - population.host_centre))) * population._kpc_per_arcsec
    (rs, alpha_rs, rt), w = population._quadrature(r2d)
    within = np.empty(rs.size)
    _kernels.enclosed(rs, tnfw_rho0(rs, alpha_rs), rt, radius, within)
    return population._unbroken_density(sigma_sub) * math.pi * float(np.sum(w * within))


def _los_maps(population, a):
    """Per plane, the line-of-sight haloes' ``P``, ``Q`` (2x2), ``|P| |Q|`` and
    ``1 / s_min(Q)`` in the smooth lens's local Jacobian ``a``.

    With the main lens linear near the image, ``beta = A x - alpha(x)``
    (plus a constant), a halo of a plane in front of the lens adds
    ``-M alpha_h(x - h)`` with ``M = (1 - b) I + b A``, and one behind it
    ``-alpha_h(N x - h')`` with ``N`` of the same form, ``b`` the plane's
    distance ratio (``los["beta"]``): ``P = M, Q = I`` or ``P = I, Q = N``.
    """
    los = population._los
    b = los["beta"][:, None, None]
    t = (1 - b) * np.eye(2) + b * a
    front = los["front"][:, None, None]
    p = np.where(front, t, np.eye(2))
    q = np.where(front, np.eye(2), t)
    sv_p = np.linalg.svd(p, compute_uv=False)
    sv_q = np.linalg.svd(q, compute_uv=False)
    return p, q, sv_p[:, 0] * sv_q[:, 0], 1.0 / sv_q[:, 1]


def _los_nodes(population):
    """The population's line-of-sight quadrature nodes (plane, (Rs, rho0, r_trunc)) and
    weights, computed once per population object."""
    nodes = population._los.get("nodes")
    if nodes is None:
        plane, (rs, alpha_rs, rt), w = population._los_quadrature()
        nodes = population._los["nodes"] = (plane, (rs, tnfw_rho0(rs, alpha_rs), rt), w)
    return nodes


def _los_sheet(population, p, q, radius):
    """The line-of-sight planes' mean convergences in a disc of ``radius``, as the
    matrix ``sum_j kappa_j P_j Q_j`` they add to ``A``."""
    plane, (rs, rho0, rt), w = _los_nodes(population)
    within = np.empty(rs.size)
    _kernels.enclosed(rs, rho0, rt, radius, within)
    per_plane = np.bincount(plane, weights=w * within, minlength=p.shape[0])
    kappa = population._los["density"] * math.pi * per_plane
    return np.einsum("j,jab,jbc->ac", kappa, p, q)


def los_halo_columns(maps, plane, x, y, rs, alpha_rs, r_trunc):
    """The kernel's columns of line-of-sight haloes: positions in the image's frame
    (``Q^-1`` of their own plane's), ``rs, rho0, r_trunc``, effective Einstein
    radii and Hessian norms, and ``pq`` (N, 10); ``maps`` is :func:`_los_maps`."""
    p, q, norm, inv_smin = maps
    xy = np.einsum("nab,nb->na", np.linalg.inv(q)[plane], np.stack([x, y], axis=1))
    hx = np.ascontiguousarray(xy[:, 0])
    hy = np.ascontiguousarray(xy[:, 1])
    rs = np.ascontiguousarray(rs, dtype=float)
    rt = np.ascontiguousarray(r_trunc, dtype=float)
    rho0 = tnfw_rho0(rs, np.asarray(alpha_rs, dtype=float))
    te = np.empty(rs.size)
    _kernels.enclosed(rs, rho0, rt, 0.0, te)
    te = np.sqrt(te) * np.sqrt(norm[plane]) * inv_smin[plane]
    hsup = np.empty(rs.size)
    _kernels.hessian_sup(rs, rho0, rt, hsup)
    hsup *= norm[plane]
    pq = np.ascontiguousarray(np.column_stack([p[plane].reshape(-1, 4),
                                               q[plane].reshape(-1, 4), norm[plane],
                                               inv_smin[plane]]))
    return hx, hy, rs, rho0, rt, te, hsup, pq


def _los_terms(task, a, lam_min):
    """The line-of-sight haloes of every realisation: the strong ones (rows for
    :func:`_kernels.excess_grid`), their starts per realisation, and each
    realisation's matrix of weak Hessians less the sheets."""
    pop = task.population
    seed = np.random.SeedSequence(task.seed.entropy,
                                  spawn_key=(*task.seed.spawn_key, _LOS_STREAM))
    rng = np.random.default_rng(seed)
    maps = _los_maps(pop, a)
    sheet = _los_sheet(pop, maps[0], maps[1], task.radius).ravel()
    s_min = float(np.linalg.svd(a, compute_uv=False)[-1])
    rows, reals = [], []
    lin = np.empty((task.n_real, 4))
    for first in range(0, task.n_real, _LOS_CHUNK):
        n_chunk = min(_LOS_CHUNK, task.n_real - first)
        h = pop._los_draw(rng, task.radius, n_chunk)
        hx, hy, rs, rho0, rt, te, hsup, pq = los_halo_columns(
            maps, h["plane"], h["x"], h["y"], h["rs"], h["alpha_rs"],
            h["r_trunc"])
        keep = np.empty(rs.size, dtype=np.bool_)
        chunk_lin = np.zeros((n_chunk, 4))
        _kernels.los_split(hx, hy, rs, rho0, rt, te, hsup, pq, h["real"], n_chunk, s_min,
                           lam_min, _STRONG, _BOX_FACTOR, _BOX_CAP, keep, chunk_lin)
        lin[first:first + n_chunk] = chunk_lin - sheet
        rows.append(np.column_stack([hx, hy, rs, rho0, rt, te, hsup, pq])[keep])
        reals.append(h["real"][keep] + first)
    real = np.concatenate(reals)
    order = np.argsort(real, kind="stable")
    strong = np.ascontiguousarray(np.concatenate(rows)[order])
    starts = np.concatenate([[0], np.cumsum(np.bincount(real, minlength=task.n_real))])
    return strong, starts.astype(np.int64), lin


def _image_task(task):
    """Flux excesses of one image: (R, S) excess and image counts."""
    pop = task.population
    rng = np.random.default_rng(task.seed)
    s_max = task.sigma[-1]
    kbar_max = _mean_convergence(pop, task.position, task.radius, s_max)
    a = task.jac
    sym = 0.5 * (a + a.T)
    lam_min = max(float(np.min(np.abs(np.linalg.eigvalsh(sym)))), 1e-6)
    halos = [pop.draw(rng, s_max, task.position, task.radius) for _ in range(task.n_real)]
    tags = [rng.random(h["mass"].size) for h in halos]
    order = [np.argsort(t) for t in tags]
    sizes = np.array([h["mass"].size for h in halos], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)

    def cat(key):
        parts = [h[key][o] for h, o in zip(halos, order, strict=True)]
        return np.ascontiguousarray(np.concatenate(parts), dtype=float)

    tag = np.ascontiguousarray(np.concatenate([t[o] for t, o in zip(tags, order, strict=True)]))
    hx = cat("x") - task.position[0]
    hy = cat("y") - task.position[1]
    rs = cat("rs")
    rho0 = tnfw_rho0(rs, cat("alpha_rs"))
    rt = cat("r_trunc")
    te = np.empty(rs.size)
    _kernels.enclosed(rs, rho0, rt, 0.0, te)
    te = np.sqrt(te)
    hsup = np.empty(rs.size)
    _kernels.hessian_sup(rs, rho0, rt, hsup)
    if pop._los is not None:
        los, los_starts, los_lin = _los_terms(task, a, lam_min)
    else:
        los = np.empty((0, 17))
        los_starts = np.zeros(task.n_real + 1, dtype=np.int64)
        los_lin = np.zeros((task.n_real, 4))
    n_s = task.sigma.size
    excess = np.empty((task.n_real, n_s))
    counts = np.empty((task.n_real, n_s), dtype=np.int64)
    _kernels.excess_grid(a[0, 0], a[0, 1], a[1, 0], a[1, 1], kbar_max, hx, hy, rs, rho0, rt,
                         te, hsup, tag, starts, task.sigma / s_max, lam_min, _STRONG, _BOX_FACTOR,
                         _BOX_CAP, _N_GRID, _MAX_IMAGES, los, los_starts, los_lin, excess,
                         counts)
    return excess, counts


def simulate_anomalies(pairs, lens, population, sigma_sub, *, n_realisations=1000,
                       radius=None, seed=0, client=None):
    r"""Monte-Carlo flux anomalies of every pair under a sub-halo population.

    For each image of each pair, sub-haloes are drawn from ``population``
    in a disc around it, at every abundance of the grid (the realisations of
    the grid share their haloes: a halo drawn at the largest abundance is
    kept at abundance :math:`\sigma` with probability
    :math:`\sigma / \sigma_{\max}`, so the likelihood varies smoothly along
    the grid). The population's mean convergence is removed as a uniform
    sheet: it is part of the smooth field that the geometric estimate and
    the neighbours' flux ratios measure, and only its fluctuation breaks
    duality. Each image's micro-images are solved in the smooth lens's local
    Jacobian (``lens``), and the pair's anomaly is
    :math:`\delta = \ln(f_1 / f_2)` with :math:`f` the flux excesses.

    Parameters
    ----------
    pairs : `~astropy.table.Table`
        The constellation: ``x1, y1, x2, y2`` in the lens's frame (arcsec),
        and ``pair_id`` (from 1 when missing).
    lens : `~lensdual.simulation.LensSystem` or `~lensdual.parametric.LenstoolModel`
        The smooth lens (a Lenstool model is taken at the population's
        source redshift).
    population : `SubhaloPopulation`
        The sub-halo population; its redshifts must be the lens's.
    sigma_sub : `~astropy.units.Quantity`
        Abundance grid, kpc^-2: at least 2 values, > 0, strictly increasing.
    n_realisations : int, optional
        Realisations per abundance, at least :data:`MIN_REALISATIONS`.
        Default 1000.
    radius : `~astropy.units.Quantity`, optional
        Disc radius of the haloes around every image. Default, per arc, the
        median separation of an image from its nearest neighbour on the same
        arc: haloes farther out perturb the neighbours alike, and the smooth
        field absorbs them.
    seed : int, optional
        Seed of the realisations (independent streams per image).
    client : dask.distributed.Client or concurrent.futures.Executor, optional
        Runs the images as parallel tasks; the result is identical to a
        serial run.

    Returns
    -------
    simulation : `AnomalySimulation`

    Raises
    ------
    TypeError
        ``pairs`` is not a Table, ``lens`` has no Jacobian, ``sigma_sub`` is
        not a Quantity in kpc^-2.
    ValueError
        Missing positions, a bad grid, too few realisations, or redshifts
        that differ between the lens and the population.
    """
    n_real = as_int(n_realisations, "n_realisations", minimum=MIN_REALISATIONS)
    return _simulate(pairs, lens, population, _as_sigma_grid(sigma_sub), n_real,
                     _as_radii(radius), seed, client)


def _as_radii(radius):
    """The user's disc radius as the (2,) radii of the two arcs, or None (the default)."""
    if radius is None:
        return None
    r = as_real(u.Quantity(radius, u.arcsec).value, "radius", minimum=0.0, inclusive=False)
    return np.array([r, r])


def _simulate(pairs, lens, population, sigma, n_real, radii, seed, client):
    """:func:`simulate_anomalies` on a checked grid and radii (None: the default), any
    number of realisations."""
    if not isinstance(population, SubhaloPopulation):
        raise TypeError(f"population must be a SubhaloPopulation, got "
                        f"{type(population).__name__}")
    lens = as_lens(lens, population)
    xy1, xy2 = _positions(pairs)
    if radii is None:
        if len(pairs) < 2:
            raise ValueError("a single pair has no neighbours to set the radius: pass radius=")
        radii = np.array([_default_radius(xy1), _default_radius(xy2)])
    client = check_client(client)
    jac1 = np.asarray(lens.jacobian(xy1 * u.arcsec), dtype=float)
    jac2 = np.asarray(lens.jacobian(xy2 * u.arcsec), dtype=float)
    _check_lens_ratios(pairs, jac1, jac2)
    pair_id = (np.asarray(pairs["pair_id"], dtype=int) if "pair_id" in pairs.colnames
               else np.arange(1, len(pairs) + 1))
    seeds = np.random.SeedSequence(seed).spawn(2 * len(pairs))
    tasks = []
    for i in range(len(pairs)):
        for arc, (jac, xy) in enumerate(((jac1, xy1), (jac2, xy2))):
            tasks.append(_ImageTask(jac[i], xy[i], float(radii[arc]), sigma, n_real,
                                    seeds[2 * i + arc], population))
    results = run_tasks(_image_task, tasks, client, ignore=(AstropyDeprecationWarning,))
    e1 = np.stack([results[2 * i][0] for i in range(len(pairs))])
    e2 = np.stack([results[2 * i + 1][0] for i in range(len(pairs))])
    c1 = np.stack([results[2 * i][1] for i in range(len(pairs))])
    c2 = np.stack([results[2 * i + 1][1] for i in range(len(pairs))])
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.log(e1) - np.log(e2)
    return AnomalySimulation(pair_id, sigma / u.kpc**2, delta, e1, e2, c1, c2, population,
                             radii)


def apply_population(pairs, lens, population, sigma_sub, *, radius=None, seed=None):
    """One realisation of a sub-halo population applied to a constellation's fluxes.

    Every image's fluxes (all bands) are multiplied by its flux excess in
    one draw of the population at abundance ``sigma_sub``, exactly as
    :func:`simulate_anomalies` models it; positions are unchanged. For
    mock data and injection-recovery tests.

    Parameters
    ----------
    pairs : `~astropy.table.Table`
        A constellation with ``x1, y1, x2, y2`` and ``flux1_<band>``,
        ``flux2_<band>`` columns (e.g. a clean one, before noise).
    lens, population, radius
        As for :func:`simulate_anomalies`.
    sigma_sub : `~astropy.units.Quantity`
        The abundance (kpc^-2, scalar, > 0).
    seed : int, optional
        Seed of the realisation.

    Returns
    -------
    perturbed : `~astropy.table.QTable`
        A copy with the fluxes scaled, and ``subhalo_excess1``,
        ``subhalo_excess2`` (the factors) and ``subhalo_delta``
        (``ln`` of their ratio) added.
    """
    return _apply_population(pairs, lens, population,
                             _as_sigma_sub(sigma_sub, positive=True), _as_radii(radius), seed)


def _apply_population(pairs, lens, population, sigma, radii, seed):
    """:func:`apply_population` for a checked abundance (kpc^-2) and radii."""
    sim = _simulate(pairs, lens, population, np.array([sigma]), 1, radii, seed, None)
    out = QTable(pairs, copy=True)
    e1 = sim.excess1[:, 0, 0]
    e2 = sim.excess2[:, 0, 0]
    for band in pair_bands(out):
        for k, e in (("1", e1), ("2", e2)):
            out[f"flux{k}_{band}"] = out[f"flux{k}_{band}"] * e
            if f"flux_err{k}_{band}" in out.colnames:
                out[f"flux_err{k}_{band}"] = out[f"flux_err{k}_{band}"] * e
    out["subhalo_excess1"] = e1
    out["subhalo_excess2"] = e2
    out["subhalo_delta"] = np.log(e1 / e2)
    return out

"""Detection-SNR maps over sub-halo mass and ``r_eff`` (paper Fig. 9) and their task plumbing.

The grid of masses is cut into chunks (tasks) that run serially, on a dask
Client or on an Executor; each chunk's numbers depend on its masses and the
seed only, so the map is the same wherever the chunks run.
"""

import math
from typing import NamedTuple

import numpy as np
from astropy import units as u
from astropy.table import QTable

from .._parallel import check_client, run_tasks
from .._validation import as_int, as_real
from ._images import _flux_excess_raw
from ._inputs import _DEFINITIONS, _as_jacobian, _as_r_eff, _as_subhalo, _check_grid, _choice, _eig
from ._radius import _unit_map
from ._reference import smacs0723_reference

__all__ = ["detection_snr_map"]

_SIGNALS = ("ratio", "log", "inverse")


class _SNRTask(NamedTuple):
    """One chunk of :func:`detection_snr_map`: its masses and the map's settings.

    Module level, so that it pickles for dask and process pools.
    """

    index: np.ndarray  # positions of the chunk's masses in the whole grid (seed their angles)
    masses: np.ndarray  # M200, Msun
    concentration: object  # "mcr", or a factor multiplying the mass-concentration relation
    jacobian: np.ndarray  # (2, 2) macro d beta / d theta at the image
    r_eff: np.ndarray
    n_angles: int
    sigma_rel: float
    percentiles: np.ndarray
    signal: str
    definition: str
    seed: object  # int or None
    z_lens: float
    z_source: float
    cosmology: object
    box: float
    n_grid: int


class _SNRRow(NamedTuple):
    """The statistics over angles of one mass, one entry per ``r_eff``."""

    theta_e: float  # point-mass Einstein radius of M200, arcsec
    concentration: float
    snr_mean: np.ndarray  # (n_r_eff,)
    snr_percentiles: np.ndarray  # (n_r_eff, n_percentiles)
    flux_excess_median: np.ndarray  # (n_r_eff,)
    max_images: np.ndarray  # (n_r_eff,) most micro-images over the angles


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

    Parameters
    ----------
    task : _SNRTask

    Returns
    -------
    rows : list of _SNRRow
        One per mass of the chunk.
    """
    a, r, n_ang, seed = task.jacobian, task.r_eff, task.n_angles, task.seed
    zl, zs, cosmology = task.z_lens, task.z_source, task.cosmology
    from ..abundance import einstein_radius
    from ..simulation.halos import mass_concentration, tnfw_halo

    k = np.arange(n_ang)
    out = []
    for i, m in zip(task.index, task.masses, strict=True):
        mq = m * u.Msun
        c = mass_concentration(mq) * (1.0 if task.concentration == "mcr" else task.concentration)
        sub = tnfw_halo(mq, c, z_lens=zl, z_source=zs, cosmology=cosmology)
        code, p0, p1, p2 = _as_subhalo(sub)
        te = float(einstein_radius(mq, zl, zs, cosmology).to_value(u.arcsec))
        if seed is None:
            phase = np.zeros(r.size)
        else:
            phase = np.random.default_rng([seed, int(i)]).random(r.size)
        phi = (k[None, :] + phase[:, None]) * (2.0 * math.pi / n_ang)
        unit = np.stack([np.cos(phi), np.sin(phi)], axis=-1) @ _unit_map(a, te, task.definition).T
        d = np.ascontiguousarray((r[:, None, None] * unit).reshape(-1, 2))
        fe, cnt = _flux_excess_raw(a, code, p0, p1, p2, d, task.box, task.n_grid)
        fe = fe.reshape(r.size, n_ang)
        snr = _signal(fe, task.signal) / task.sigma_rel
        out.append(_SNRRow(
            theta_e=te, concentration=c, snr_mean=snr.mean(axis=1),
            snr_percentiles=np.percentile(snr, task.percentiles, axis=1).T,
            flux_excess_median=np.median(fe, axis=1),
            max_images=cnt.reshape(r.size, n_ang).max(axis=1)))
    return out


def _check_pool(client, executor):
    if client is not None and executor is not None:
        raise ValueError("give client or executor (its alias), not both")
    return check_client(client if client is not None else executor)


def _as_concentration(concentration):
    if isinstance(concentration, str):
        if concentration != "mcr":
            raise ValueError(
                f"concentration must be 'mcr' or a positive factor, got {concentration!r}"
            )
        return "mcr"
    return as_real(concentration, "concentration", minimum=0.0, inclusive=False)


def _as_percentiles(percentiles):
    try:
        q = np.atleast_1d(np.asarray(percentiles, dtype=np.float64))
    except (TypeError, ValueError):
        raise TypeError(f"percentiles must be real numbers, got {percentiles!r}") from None
    if q.ndim != 1 or q.size == 0 or not ((q >= 0) & (q <= 100)).all():
        raise ValueError(f"percentiles must be a non-empty sequence in [0, 100], got {percentiles}")
    return q


def _as_seed(seed):
    if isinstance(seed, np.random.Generator):
        return int(seed.integers(0, 2**63 - 1))
    if seed is not None:
        return as_int(seed, "seed", minimum=0)
    return None


def _snr_table(m, r, q, rows):
    """The map's table from one `_SNRRow` per mass (``r_eff`` varying fastest)."""
    nr = r.size
    cols = {
        "mass": np.repeat(m, nr) * u.Msun,
        "concentration": np.repeat([row.concentration for row in rows], nr),
        "theta_e": np.repeat([row.theta_e for row in rows], nr) * u.arcsec,
        "r_eff": np.tile(r, m.size),
        "snr_mean": np.concatenate([row.snr_mean for row in rows]),
    }
    snr = np.vstack([row.snr_percentiles for row in rows])
    for j, qq in enumerate(q):
        cols[f"snr_p{qq:g}"] = snr[:, j]
    cols["flux_excess_median"] = np.concatenate([row.flux_excess_median for row in rows])
    cols["max_images"] = np.concatenate([row.max_images for row in rows])
    return QTable(cols)


def detection_snr_map(masses, r_eff, *, jacobian=None, sigma_rel=None, sigma_pos=None,
                      concentration="mcr", percentiles=(50, 68, 95), n_angles=36,
                      signal="ratio", definition="paper", seed=None, z_lens=0.39,
                      z_source=2.2, cosmology=None, box=10.0, n_grid=400, client=None,
                      executor=None, chunk_size=1, test="geometric", flux_rel_err=0.02):
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
    test, flux_rel_err
        With ``jacobian=None`` and ``sigma_rel=None``: the test whose error the
        default ``sigma_rel`` is (``"geometric"``, default, or ``"joint"``:
        the joint test's prediction error with fluxes of relative error
        ``flux_rel_err``), see :func:`smacs0723_reference`. For a user's own
        constellation, pass ``sigma_rel`` from its duality table
        (``ln_mu_size_err``, or ``ln_mu_predicted_err`` of the joint test).
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
    conc = _as_concentration(concentration)
    q = _as_percentiles(percentiles)
    n_ang = as_int(n_angles, "n_angles", minimum=1)
    _choice(signal, "signal", _SIGNALS)
    _choice(definition, "definition", _DEFINITIONS)
    seed = _as_seed(seed)
    zl, zs = as_redshifts(z_lens, z_source)
    cosmology = as_cosmology(cosmology)
    box, n = _check_grid(box, n_grid)
    cs = as_int(chunk_size, "chunk_size", minimum=1)
    pool = _check_pool(client, executor)
    if test != "geometric" and (sigma_rel is not None or jacobian is not None):
        raise ValueError("test only chooses the default sigma_rel of the SMACS0723 reference; "
                         "with a jacobian or sigma_rel, pass the joint test's error as sigma_rel")
    if sigma_rel is not None:
        sigma = as_real(sigma_rel, "sigma_rel", minimum=0.0, inclusive=False)
        if sigma_pos is not None:
            raise ValueError("give sigma_rel or sigma_pos, not both (sigma_pos sets the "
                             "bootstrap error that sigma_rel would replace)")
    meta = {}
    if jacobian is None:
        sp = 0.06 * u.arcsec if sigma_pos is None else sigma_pos
        as_angle_scalar(sp, "sigma_pos", allow_zero=False)
        ref = smacs0723_reference(sigma_pos=sp, test=test, flux_rel_err=flux_rel_err)
        a = ref["jacobian"]
        if sigma_rel is None:
            sigma = ref["sigma_rel"]
            meta["sigma_pos"] = sp
            meta["test"] = test
    else:
        a = _as_jacobian(jacobian)
        if sigma_rel is None:
            raise ValueError("sigma_rel is required with a jacobian (sigma_pos only sets the "
                             "bootstrap error of the default SMACS0723 reference)")
    _eig(a)
    settings = _SNRTask(index=None, masses=None, concentration=conc, jacobian=a, r_eff=r,
                        n_angles=n_ang, sigma_rel=sigma, percentiles=q, signal=signal,
                        definition=definition, seed=seed, z_lens=zl, z_source=zs,
                        cosmology=cosmology, box=box, n_grid=n)
    tasks = [settings._replace(index=np.arange(i, min(i + cs, m.size)), masses=m[i:i + cs])
             for i in range(0, m.size, cs)]
    rows = [row for chunk in run_tasks(_snr_chunk, tasks, pool) for row in chunk]
    t = _snr_table(m, r, q, rows)
    meta.update({"jacobian": a.tolist(), "sigma_rel": sigma, "signal": signal,
                 "definition": definition, "concentration": conc, "n_angles": n_ang,
                 "percentiles": q.tolist(), "seed": seed, "z_lens": zl, "z_source": zs})
    t.meta.update(meta)
    return t

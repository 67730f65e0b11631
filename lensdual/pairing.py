"""Pairing the point sources of two lens arcs (the paper's Fig. 3).

The duality test needs *pairs*: the images of one source on arc L1 and on
arc L2. The paper paired its SMACS0723 constellation by eye;
:func:`pairs_from_ids` builds the pairs table from such a manual list of
catalogue ids, and :func:`pair_constellations` finds the pairs automatically
(or checks a manual list against the best-fitting map).

The two constellations are related by the relative lens mapping, locally
almost affine, ``x1 = A x2 + offset`` (``A`` is the relative Jacobian
``J = d theta(L1) / d theta(L2)`` of :ref:`pairs-table`), of either parity
(``det A < 0`` for a fold pair), with ``|det A|`` anywhere from ~0.1 to ~10,
any rotation and a strong anisotropic stretch (arcs are stretched images),
plus a small non-linearity. Neither
catalogue is clean: some sources have no counterpart, some detections are
spurious. See the "Pairing" page of the documentation for the algorithm and
its measured accuracy.
"""

import warnings
from dataclasses import dataclass
from itertools import combinations

import numpy as np
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.table import QTable, Table
from scipy.optimize import linear_sum_assignment
from scipy.spatial import ConvexHull, QhullError, cKDTree
from scipy.special import fdtri

from . import _pairing_kernels
from ._frames import mean_direction, tangent_xy
from ._knots import KnotPairs, pairs_from_knots, read_macro_images
from ._pairs_table import (
    ID_COLUMNS,
    PAIR_ID,
    SKY_COLUMNS,
    check_unique_pair_ids,
    flux_col,
    flux_err_col,
    positions,
    xy_cols,
)
from ._validation import as_angle_scalar, as_positions, as_real, check_unique_rows

__all__ = ["KnotPairs", "pair_constellations", "pairs_from_ids", "pairs_from_knots",
           "read_macro_images"]

# ---------------------------------------------------------------------------
# tuning constants (documented in the docstring of pair_constellations)
# ---------------------------------------------------------------------------

#: Default inlier tolerance, as a fraction of the smaller of the two median
#: nearest-neighbour distances of the catalogues.
_TOLERANCE_FRACTION = 0.3
#: Default max_residual: this many robust rms of the fitted pairs ...
_MAX_RESIDUAL_RMS = 5.0
#: ... but never below this fraction of the tolerance.
_MAX_RESIDUAL_FLOOR = 1.0 / 3.0
#: ... and never above this fraction of the median nearest-neighbour distance
#: (or the tolerance, if larger).
_GATE_CAP = 0.5
#: Colour differences above this many colour_sigma never pair.
_COLOUR_GATE = 5.0
#: Triangles flatter than this (4 sqrt(3) area / sum of squared sides, 1 for
#: an equilateral triangle) in the catalogue's whitened frame are not used.
_MIN_TRIANGLE_SHAPE = 0.08
#: All triangles of a catalogue up to this many, else a random subset (seed).
_MAX_TRIANGLES = 6000
#: Triangle descriptors: barycentric coordinates of this many other points
#: (those nearest to the triangle's centroid in barycentric coordinates).
_N_DESC_POINTS = 2
#: Candidate ordered triangles of catalogue 1 per triangle of catalogue 2
#: (nearest descriptors): as many as fit in the budget, at least _K_DESCRIPTOR.
_K_DESCRIPTOR = 3
_HYPOTHESIS_BUDGET = 12000
#: Hypotheses are drawn (with the seed) down to this many when there are more.
_MAX_HYPOTHESES = 30000
#: The default bound on plausible maps (``max_magnification`` of
#: :func:`pair_constellations`): |det A| within [1/b, b] and a stretch (ratio of
#: the singular values) below b.
DEFAULT_MAX_MAGNIFICATION = 20.0
#: Refined hypotheses are compared by their MSAC score at _SELECT_RMS times
#: the smallest robust rms among those with nearly the most inliers, but at
#: least _SELECT_FRACTION of the tolerance.
_SELECT_RMS = 4.0
_SELECT_FRACTION = 0.5
#: Hypotheses refined by local optimisation, and its iterations.
_N_REFINE = 24
_REFINE_ITER = 8
#: Automatic order: a quadratic map is considered from this many pairs on,
#: and kept when an F-test prefers it at this false-alarm probability.
_QUADRATIC_MIN_PAIRS = 8
_F_FALSE_ALARM = 1e-2
#: Trimmed fits leave out pairs beyond max(_TRIM_RMS robust rms,
#: _TRIM_FLOOR tolerance).
_TRIM_RMS = 4.0
_TRIM_FLOOR = 0.25
#: Fewest consistent pairs the automatic search accepts.
_MIN_AUTO_PAIRS = 4
#: The gate of a pair is never narrowed by the chance density below this many
#: standard deviations of the residual per axis.
_CHANCE_GATE_FLOOR = 2.0
#: ... and not at all where the tail of true pairs' residuals (this fraction of
#: them, spread evenly over the gate) is denser than the chance coincidences.
_TAIL_FRACTION = 0.2
#: When the best map leaves most points of the larger catalogue unmatched, the
#: search is repeated on this many decoys of catalogue 2 (its points
#: scrambled), and the map is
#: only accepted with at least _DECOY_MARGIN times the decoys' most inliers.
_N_DECOYS = 2
_DECOY_MARGIN = 1.3
#: Scoring costs about (hypotheses x (N1 + N2)) operations (a few grid cells
#: per mapped point, ``lensdual._pairing_kernels``); above this many, the
#: hypotheses are drawn (with the seed) down to the number that fits: all
#: _MAX_HYPOTHESES up to 500 points per catalogue.
_MAX_SCORE_WORK = 3e7
#: With flux columns, hypotheses are also drawn from the triangles of the
#: this many brightest points of each catalogue (scored first).
_N_BRIGHT = 24
#: Triangles whose descriptors are computed at once (bounds the (T, N, 3) arrays).
_TRIANGLE_CHUNK = 512


# ---------------------------------------------------------------------------
# input handling
# ---------------------------------------------------------------------------


def _column_quantity(table, column, name):
    """A table column as an angle Quantity (TypeError when it has no angle unit)."""
    if column not in table.colnames:
        raise ValueError(f"{name} has no column {column!r} (columns: {table.colnames})")
    col = table[column]
    if isinstance(col, SkyCoord):
        raise TypeError(
            f"{name} column {column!r} is a SkyCoord: pass position_columns={column!r} "
            "(a single name) to project it onto the tangent plane"
        )
    unit = getattr(col, "unit", None)
    if unit is None or u.Unit(unit).physical_type != "angle":
        raise TypeError(
            f"{name} column {column!r} must be an angle Quantity (e.g. arcsec), got unit "
            f"{unit}; convert pixel positions to arcsec (pixel scale) or use the "
            "sky_centroid column"
        )
    return u.Quantity(col, copy=False)


def _raw_catalog(catalog, name, position_columns, id_column):
    """Return (ids, positions Quantity (N, 2) or SkyCoord (N,))."""
    if isinstance(catalog, u.Quantity):
        pos = as_positions(catalog, name) * u.arcsec
        return np.arange(len(pos)), pos
    if not isinstance(catalog, Table):
        if isinstance(catalog, SkyCoord):
            return np.arange(len(catalog)), catalog
        raise TypeError(
            f"{name} must be an astropy Table/QTable of detections or an (N, 2) angle "
            f"Quantity of positions, got {type(catalog).__name__}"
        )
    if isinstance(position_columns, str):
        if position_columns not in catalog.colnames:
            raise ValueError(
                f"{name} has no column {position_columns!r} (columns: {catalog.colnames})"
            )
        col = catalog[position_columns]
        if isinstance(col, SkyCoord):
            pos = col
        else:
            unit = getattr(col, "unit", None)
            if unit is None or u.Unit(unit).physical_type != "angle":
                raise TypeError(
                    f"{name} column {position_columns!r} must be a SkyCoord or an (N, 2) "
                    f"angle Quantity, got unit {unit}"
                )
            pos = as_positions(u.Quantity(col), f"{name}[{position_columns!r}]") * u.arcsec
    else:
        try:
            xcol, ycol = position_columns
        except (TypeError, ValueError):
            raise TypeError(
                "position_columns must be two column names (x, y) or the name of one "
                f"SkyCoord or (N, 2) column, got {position_columns!r}"
            ) from None
        x = _column_quantity(catalog, xcol, name)
        y = _column_quantity(catalog, ycol, name)
        pos = as_positions(
            np.column_stack([x.to_value(u.arcsec), y.to_value(u.arcsec)]) * u.arcsec, name
        ) * u.arcsec
    if id_column is None:
        ids = np.arange(len(catalog))
    else:
        if id_column not in catalog.colnames:
            raise ValueError(
                f"{name} has no id column {id_column!r}; pass id_column=None to use the "
                "row numbers"
            )
        ids = np.asarray(catalog[id_column])
        uniq, counts = np.unique(ids, return_counts=True)
        if (counts > 1).any():
            raise ValueError(
                f"{name} column {id_column!r} has repeated id(s) {uniq[counts > 1].tolist()}"
            )
    return ids, pos


def _mean_direction(sky1, sky2):
    """Mean direction of both catalogues (see :func:`lensdual._frames.mean_direction`)."""
    return mean_direction(sky1, sky2)


def _project(sky, centre):
    """Gnomonic offsets (x west, y north) from ``centre`` in arcsec, shape (N, 2)."""
    return np.column_stack(tangent_xy(sky, centre))


def _catalogs(catalog1, catalog2, position_columns, id_column, reference):
    """Both catalogues in one frame: (ids1, xy1, sky1, ids2, xy2, sky2, tangent point)."""
    ids1, pos1 = _raw_catalog(catalog1, "catalog1", position_columns, id_column)
    ids2, pos2 = _raw_catalog(catalog2, "catalog2", position_columns, id_column)
    sky_kind = (isinstance(pos1, SkyCoord), isinstance(pos2, SkyCoord))
    if sky_kind[0] != sky_kind[1]:
        raise ValueError(
            "catalog1 and catalog2 must both give sky positions (SkyCoord) or both "
            "tangent-plane positions, not one of each"
        )
    if sky_kind[0]:
        if len(pos1) == 0 or len(pos2) == 0:
            raise ValueError("catalog1 and catalog2 must hold at least one position each")
        if reference is None:
            reference = _mean_direction(pos1, pos2)
        elif not isinstance(reference, SkyCoord) or not reference.isscalar:
            raise TypeError(f"reference must be a scalar SkyCoord, got {reference!r}")
        xy1, xy2 = _project(pos1, reference), _project(pos2, reference)
        for name, xy in (("catalog1", xy1), ("catalog2", xy2)):
            as_positions(xy * u.arcsec, name)
        return ids1, xy1, pos1, ids2, xy2, pos2, reference
    return ids1, pos1.value, None, ids2, pos2.value, None, None


def catalog_positions(catalog, name, position_columns, reference):
    """Tangent-plane positions (N, 2) in arcsec of one catalogue (for figures)."""
    _, pos = _raw_catalog(catalog, name, position_columns, None)
    if isinstance(pos, SkyCoord):
        if reference is None:
            raise ValueError(
                f"{name} gives sky positions but no tangent point is known (pairs.meta"
                "['reference'])"
            )
        return _project(pos, reference)
    return pos.value


def pairs_positions(pairs):
    """(x1, x2): the (N, 2) arcsec positions of a pairs table."""
    if not isinstance(pairs, Table):
        raise TypeError(f"pairs must be an astropy Table or QTable, got {type(pairs).__name__}")
    theta1, theta2 = positions(pairs)
    return theta1.to_value(u.arcsec), theta2.to_value(u.arcsec)


def _id_pairs(id_pairs, name):
    """(M,) id1 and id2 arrays from a table with id1/id2 columns or an (M, 2) array."""
    if isinstance(id_pairs, Table):
        if all(c in id_pairs.colnames for c in ID_COLUMNS):
            id1, id2 = (np.asarray(id_pairs[c]) for c in ID_COLUMNS)
        elif len(id_pairs.colnames) == 2:
            id1 = np.asarray(id_pairs[id_pairs.colnames[0]])
            id2 = np.asarray(id_pairs[id_pairs.colnames[1]])
        else:
            raise ValueError(
                f"{name} must have columns 'id1' and 'id2' (or exactly two columns), got "
                f"{id_pairs.colnames}"
            )
    else:
        if isinstance(id_pairs, u.Quantity):
            raise TypeError(f"{name} must hold catalogue ids, not a Quantity")
        arr = np.asarray(id_pairs)
        if arr.ndim != 2 or arr.shape[1] != 2:
            raise ValueError(
                f"{name} must be a table with columns id1, id2 or an (M, 2) array of id "
                f"pairs, got shape {arr.shape}"
            )
        id1, id2 = arr[:, 0], arr[:, 1]
    if len(id1) == 0:
        raise ValueError(f"{name} is empty")
    return id1, id2


def _rows_of(ids, wanted, name, cat_name):
    """Row numbers of ``wanted`` ids in ``ids``; ValueError for unknown or repeated ids."""
    uniq, counts = np.unique(wanted, return_counts=True)
    if (counts > 1).any():
        raise ValueError(
            f"{name}: {cat_name} id(s) {uniq[counts > 1].tolist()} appear in more than one "
            "pair (every point source can have only one counterpart)"
        )
    lookup = {v.item() if hasattr(v, "item") else v: k for k, v in enumerate(ids)}
    rows, unknown = [], []
    for v in wanted:
        key = v.item() if hasattr(v, "item") else v
        if key in lookup:
            rows.append(lookup[key])
        else:
            unknown.append(key)
    if unknown:
        raise ValueError(f"{name}: id(s) {unknown} not found in {cat_name}")
    return np.asarray(rows, dtype=np.int64)


def _colours(catalog, flux_columns, name, units):
    """Colours (N, K-1) in mag, -2.5 log10(f_k / f_0), NaN where a flux is not > 0,
    and the mean magnitude (N,) over the bands with a flux (NaN without any)."""
    if not isinstance(catalog, Table):
        raise TypeError(f"flux_columns needs {name} to be a table, got {type(catalog).__name__}")
    fluxes = []
    for k, col in enumerate(flux_columns):
        if col not in catalog.colnames:
            raise ValueError(f"{name} has no flux column {col!r}")
        val = catalog[col]
        unit = getattr(val, "unit", None)
        if units[k] is None:
            units[k] = unit
        if unit is not None and units[k] is not None:
            try:
                f = u.Quantity(val).to_value(units[k])
            except u.UnitConversionError:
                raise ValueError(
                    f"flux column {col!r} of catalog1 and catalog2 have incompatible units "
                    f"({units[k]} and {unit})"
                ) from None
        else:
            f = np.asarray(val, dtype=float)
        fluxes.append(np.asarray(f, dtype=float))
    f = np.column_stack(fluxes)
    with np.errstate(divide="ignore", invalid="ignore"):
        ok = np.isfinite(f) & (f > 0)
        mag = np.where(ok, -2.5 * np.log10(np.where(ok, f, 1.0)), np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows: NaN
        mean_mag = np.nanmean(mag, axis=1)
    return mag[:, 1:] - mag[:, :1], mean_mag


def _check_flux_columns(flux_columns):
    if flux_columns is None:
        return None
    if isinstance(flux_columns, str):
        raise TypeError(
            "flux_columns must be a sequence of at least two column names (e.g. "
            f"['peak_F150W', 'peak_F200W']), got the string {flux_columns!r}"
        )
    cols = list(flux_columns)
    if len(cols) < 2 or not all(isinstance(c, str) for c in cols):
        raise ValueError(
            f"flux_columns must name at least two flux columns (one colour), got {flux_columns!r}"
        )
    return cols


# ---------------------------------------------------------------------------
# maps: x1 = A (x2 - centre) + c0 [+ quadratic terms in (x2 - centre)]
# ---------------------------------------------------------------------------


def _features(q, centre, order):
    d = q - centre
    cols = [np.ones(len(q)), d[:, 0], d[:, 1]]
    if order == 2:
        cols += [d[:, 0] ** 2, d[:, 0] * d[:, 1], d[:, 1] ** 2]
    return np.column_stack(cols)


def _fit(p, q, centre, order):
    """Least-squares map coefficients (K, 2): x1 = features(x2) @ coef."""
    coef, *_ = np.linalg.lstsq(_features(q, centre, order), p, rcond=None)
    return coef


def _apply(coef, q, centre):
    order = 2 if len(coef) == 6 else 1
    return _features(q, centre, order) @ coef


def _jacobians(coef, q, centre):
    """Local Jacobians d x1 / d x2 at the points q, shape (N, 2, 2)."""
    jac = np.broadcast_to(coef[1:3].T, (len(q), 2, 2)).copy()
    if len(coef) == 6:
        d = q - centre
        c3, c4, c5 = coef[3], coef[4], coef[5]
        jac[:, :, 0] += 2 * c3[None, :] * d[:, :1] + c4[None, :] * d[:, 1:]
        jac[:, :, 1] += c4[None, :] * d[:, :1] + 2 * c5[None, :] * d[:, 1:]
    return jac


def _metric(jac, normalise=False):
    """Inverse of C = (I + J J^T) / 2, shape (..., 2, 2).

    With equal, independent position noise sigma in both catalogues, the
    residual r = x1 - f(x2) has covariance 2 sigma^2 C, so r^T C^-1 r is the
    noise-weighted squared residual in arcsec^2; for J a rotation (or
    reflection) it is the plain squared distance.

    ``normalise``: the inverse of C / sqrt(det C) instead, whose unit circle
    has the same area for every map. The search compares maps with it: with
    C itself, a map that stretches strongly would accept chance coincidences
    over a larger area of catalogue 1.
    """
    c = 0.5 * (np.eye(2) + jac @ np.swapaxes(jac, -1, -2))
    det = c[..., 0, 0] * c[..., 1, 1] - c[..., 0, 1] * c[..., 1, 0]
    scale = 1.0 / (np.sqrt(det) if normalise else det)
    inv = np.empty_like(c)
    inv[..., 0, 0] = c[..., 1, 1] * scale
    inv[..., 1, 1] = c[..., 0, 0] * scale
    inv[..., 0, 1] = -c[..., 0, 1] * scale
    inv[..., 1, 0] = -c[..., 1, 0] * scale
    return inv


def _residuals2(coef, p, q, centre, normalise=False):
    """Squared metric residuals of all combinations, shape (N1, N2)."""
    qm = _apply(coef, q, centre)
    minv = _metric(_jacobians(coef, q, centre), normalise)  # (N2, 2, 2)
    rx = p[:, None, 0] - qm[None, :, 0]
    ry = p[:, None, 1] - qm[None, :, 1]
    return minv[:, 0, 0] * rx * rx + 2 * minv[:, 0, 1] * rx * ry + minv[:, 1, 1] * ry * ry


def _pair_residuals2(coef, p, q, centre):
    """Squared metric residuals of matched rows p[k] <-> q[k]."""
    r = p - _apply(coef, q, centre)
    minv = _metric(_jacobians(coef, q, centre))
    rx, ry = r[:, 0], r[:, 1]
    return minv[:, 0, 0] * rx * rx + 2 * minv[:, 0, 1] * rx * ry + minv[:, 1, 1] * ry * ry


def _leverage(coef, q, q_fit, centre):
    """Leverage phi(q)^T (Phi^T Phi)^-1 phi(q) of points q for a fit on q_fit."""
    order = 2 if len(coef) == 6 else 1
    phi_fit = _features(q_fit, centre, order)
    phi = _features(q, centre, order)
    cov = np.linalg.pinv(phi_fit.T @ phi_fit)
    return np.einsum("nk,kl,nl->n", phi, cov, phi)


# ---------------------------------------------------------------------------
# hypotheses
# ---------------------------------------------------------------------------


def _whitening(x):
    """Robust centre and whitening matrix W (x' = W (x - centre) has unit covariance)."""
    centre = np.median(x, axis=0)
    keep = np.ones(len(x), dtype=bool)
    w = np.eye(2)
    for _ in range(3):
        sub = x[keep]
        centre = sub.mean(axis=0)
        cov = np.cov(sub.T) if len(sub) > 2 else np.eye(2)
        cov = cov + 1e-9 * max(np.trace(cov), 1e-300) * np.eye(2)
        evals, evecs = np.linalg.eigh(cov)
        evals = np.maximum(evals, 1e-6 * evals.max() + 1e-300)
        w = (evecs / np.sqrt(evals)) @ evecs.T
        d2 = (((x - centre) @ w.T) ** 2).sum(axis=1)
        new = d2 <= max(9.0, np.median(d2) * 3.0)
        if new.sum() < max(3, int(0.6 * len(x))) or (new == keep).all():
            break
        keep = new
    return centre, w


_PERMUTATIONS = np.array([[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]])


def _barycentric_triangles(x, rng):
    """Triangles of a catalogue and their affine-invariant descriptors.

    Returns the vertex triplets (T, 3) and, per triplet, the barycentric
    coordinates (T, n_desc, 3) of the ``_N_DESC_POINTS`` other points nearest
    to its centroid in barycentric coordinates (an affine-invariant choice).
    """
    n = len(x)
    n_tri = n * (n - 1) * (n - 2) // 6
    if n_tri <= _MAX_TRIANGLES:
        tri = np.array(list(combinations(range(n), 3)), dtype=np.int64)
    else:
        draws = np.sort(rng.integers(0, n, (_MAX_TRIANGLES, 3)), axis=1)
        distinct = (draws[:, 0] < draws[:, 1]) & (draws[:, 1] < draws[:, 2])
        tri = np.unique(draws[distinct], axis=0)
    # leave out (nearly) collinear triplets, judged in the catalogue's whitened frame
    c, w = _whitening(x)
    v = ((x - c) @ w.T)[tri]
    e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    sides2 = (e1**2).sum(1) + (e2**2).sum(1) + ((v[:, 2] - v[:, 1]) ** 2).sum(1)
    tri = tri[4 * np.sqrt(3) * area / np.maximum(sides2, 1e-300) > _MIN_TRIANGLE_SHAPE]
    if len(tri) == 0 or n < 3 + _N_DESC_POINTS:
        # too few points for descriptors: every triangle matches every other
        return tri, np.zeros((len(tri), _N_DESC_POINTS, 3))
    desc = np.empty((len(tri), _N_DESC_POINTS, 3))
    for start in range(0, len(tri), _TRIANGLE_CHUNK):  # bounded (T, N, 3) arrays
        sub = tri[start:start + _TRIANGLE_CHUNK]
        v = x[sub]
        e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
        det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        r = x[None, :, :] - v[:, None, 0, :]  # (T, N, 2)
        lam1 = (r[..., 0] * e2[:, None, 1] - r[..., 1] * e2[:, None, 0]) / det[:, None]
        lam2 = (e1[:, None, 0] * r[..., 1] - e1[:, None, 1] * r[..., 0]) / det[:, None]
        bary = np.stack([1.0 - lam1 - lam2, lam1, lam2], axis=2)  # (T, N, 3)
        dist = ((bary - 1.0 / 3.0) ** 2).sum(axis=2)
        dist[np.arange(len(sub))[:, None], sub] = np.inf
        kth = np.arange(_N_DESC_POINTS)
        near = np.argpartition(dist, kth, axis=1)[:, :_N_DESC_POINTS]
        desc[start:start + len(sub)] = np.take_along_axis(bary, near[:, :, None], axis=1)
    return tri, desc


def _triangle_matches(p, q, rng):
    """Matched triangles: vertex rows (H, 3) of catalogue 2 and, in order, of catalogue 1.

    Triangles of catalogue 2 are matched to ordered triangles of catalogue 1
    by the barycentric coordinates of their nearest points, which any affine
    map preserves.
    """
    tri1, d1 = _barycentric_triangles(p, rng)
    tri2, d2 = _barycentric_triangles(q, rng)
    if len(tri1) == 0 or len(tri2) == 0:
        return np.empty((0, 3), dtype=np.int64), np.empty((0, 3), dtype=np.int64)
    # all 6 vertex orders of catalogue 1: descriptor = coordinates 1 and 2 in that order
    perm = _PERMUTATIONS
    key1 = np.stack([d1[:, :, perm[o, 1:]] for o in range(len(perm))], axis=1)  # (T1, 6, nd, 2)
    key1 = key1.reshape(len(tri1) * len(perm), -1)
    key2 = d2[:, :, 1:].reshape(len(tri2), -1)
    k = min(len(key1), max(_K_DESCRIPTOR, _HYPOTHESIS_BUDGET // len(tri2)))
    _, idx = cKDTree(key1).query(key2, k=k)
    idx = idx.reshape(len(tri2), k)
    t2 = np.repeat(np.arange(len(tri2)), k)
    t1, o = np.divmod(idx.ravel(), len(perm))
    return tri2[t2], np.take_along_axis(tri1[t1], perm[o], axis=1)


def _brightest(mag, n):
    """Rows of the ``n`` brightest points (smallest magnitude; NaN last)."""
    return np.argsort(np.where(np.isfinite(mag), mag, np.inf), kind="stable")[:n]


def _hypotheses(p, q, parity, rng, mags, bound):
    """Affine maps (A (H, 2, 2), b (H, 2)) from matched triangles, x1 = A x2 + b.

    The triangles are those of all points (:func:`_triangle_matches`) and,
    with ``mags`` (the mean magnitudes of both catalogues), those of the
    ``_N_BRIGHT`` brightest points of each catalogue, described by each
    other only: in a catalogue crowded with faint spurious detections, these
    are the triangles most likely made of true counterparts. The bright
    hypotheses are kept first when the hypotheses must be drawn down. Only
    maps with ``|det A|`` in ``[1/bound, bound]`` and a stretch below ``bound``
    are kept.
    """
    src, dst = _triangle_matches(p, q, rng)
    n_first = 0
    if mags is not None and max(len(p), len(q)) > _N_BRIGHT:
        b1, b2 = _brightest(mags[0], _N_BRIGHT), _brightest(mags[1], _N_BRIGHT)
        src_b, dst_b = _triangle_matches(p[b1], q[b2], rng)
        src, dst = np.vstack([b2[src_b], src]), np.vstack([b1[dst_b], dst])
        n_first = len(src_b)
    max_hyp = min(_MAX_HYPOTHESES,
                  max(_N_REFINE, int(_MAX_SCORE_WORK / (len(p) + len(q)))))
    if len(dst) > max_hyp:
        first = np.arange(min(n_first, max_hyp))
        rest = n_first + rng.choice(len(dst) - n_first, max_hyp - len(first), replace=False)
        keep = np.concatenate([first, np.sort(rest)])
        dst, src = dst[keep], src[keep]
    m = np.concatenate([q[src], np.ones(src.shape + (1,))], axis=2)  # (H, 3, 3)
    det_m = np.linalg.det(m)
    ok = np.abs(det_m) > 1e-12 * np.abs(m).max(axis=(1, 2)) ** 2
    m, dst = m[ok], dst[ok]
    coef = np.linalg.solve(m, p[dst])  # (H, 3, 2): rows x, y, 1
    a = np.swapaxes(coef[:, :2, :], 1, 2)
    b = coef[:, 2, :]
    det = a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]
    fro2 = (a**2).sum(axis=(1, 2))
    adet = np.abs(det)
    disc = np.sqrt(np.maximum(fro2**2 - 4 * det**2, 0.0))
    smax = np.sqrt(0.5 * (fro2 + disc))
    smin = adet / np.maximum(smax, 1e-300)
    ok = (adet > 1.0 / bound) & (adet < bound) & (smax < bound * smin)
    if parity is not None:
        ok &= np.sign(det) == parity
    return a[ok], b[ok]


class _Inliers:
    """Inliers of maps from catalogue 2 onto catalogue 1 (numba kernels on a grid of catalogue 1).

    Inliers are mutual nearest neighbours closer than ``sqrt(tau2)`` in the
    normalised noise metric (:func:`_metric`) and, with ``colour_ok``
    (N1, N2), with compatible colours.
    """

    def __init__(self, p, tau2, colour_ok):
        self.p = np.ascontiguousarray(p, dtype=float)
        self.tau2 = float(tau2)
        self.grid = _pairing_kernels.grid(self.p, np.sqrt(self.tau2))
        self.use_colour = colour_ok is not None
        self.colour_ok = (np.ascontiguousarray(colour_ok) if self.use_colour
                          else np.ones((1, 1), dtype=bool))

    def score(self, a, b, q):
        """Inlier counts and MSAC scores (sum of 1 - d^2 / tau^2) of affine hypotheses."""
        return _pairing_kernels.score_hypotheses(
            np.ascontiguousarray(a, dtype=float), np.ascontiguousarray(b, dtype=float),
            np.ascontiguousarray(q, dtype=float), self.tau2, self.p, *self.grid,
            self.colour_ok, self.use_colour)

    def of_map(self, coef, q, centre):
        """Inliers (i, j, squared metric distances) of the map ``coef`` (sorted by j)."""
        qm = np.ascontiguousarray(_apply(coef, q, centre))
        minv = np.ascontiguousarray(_metric(_jacobians(coef, q, centre), normalise=True))
        return _pairing_kernels.mutual_inliers(qm, minv, self.tau2, self.p, *self.grid,
                                               self.colour_ok, self.use_colour)


def _choose_order(p, q, centre, order):
    """Map order for the pairs p <-> q: ``order``, or (None) an F-test of quadratic vs affine.

    The quadratic terms are kept when they lower the residual sum of squares
    more than chance would at p < 0.001 (and there are at least 8 pairs).
    """
    if order == 1 or len(p) < _QUADRATIC_MIN_PAIRS:
        return 1
    if order == 2:
        return 2
    rss = []
    for o in (1, 2):
        coef = _fit(p, q, centre, o)
        rss.append(float(_pair_residuals2(coef, p, q, centre).sum()))
    dof = 2 * len(p) - 12
    if rss[1] <= 0:
        return 2 if rss[0] > 0 else 1
    fstat = (rss[0] - rss[1]) / 6.0 / (rss[1] / dof)
    return 2 if fstat > fdtri(6, dof, 1.0 - _F_FALSE_ALARM) else 1


def _robust_fit(p, q, i, j, centre, order, floor):
    """Outlier-resistant least squares on the pairs (i, j).

    Backward elimination: the worst pair is left out while its residual from
    the map fitted *without it* exceeds max(4 robust rms of the others,
    floor); then every pair within that limit of the final map is taken
    back, and the process repeated until the kept set is stable. With
    ``order=None`` this is done for an affine map first; the quadratic map
    (its elimination started from the pairs the affine map keeps) is used
    instead when an F-test prefers it on the pairs the affine map keeps, or
    when it keeps more pairs and the F-test prefers it on those.
    Returns (coef, kept mask, robust rms, rms) of the kept pairs.
    """
    pi, qj = p[i], q[j]
    res = _eliminate(pi, qj, centre, order or 1, floor)
    if order is None and res[1].sum() >= _QUADRATIC_MIN_PAIRS:
        keep = res[1]
        # start from the pairs the affine map keeps: the quadratic map may take
        # back pairs that show the curvature, but cannot bend to outliers
        res2 = _eliminate(pi, qj, centre, 2, floor, keep)
        if _choose_order(pi[keep], qj[keep], centre, None) == 2:
            return res2
        keep2 = res2[1]
        if keep2.sum() > keep.sum() and _choose_order(
                pi[keep2], qj[keep2], centre, None) == 2:
            return res2
    return res


def _eliminate(pi, qj, centre, order, floor, keep=None):
    """Backward elimination of outlying pairs for a map of fixed order."""
    n = len(pi)
    keep = np.ones(n, dtype=bool) if keep is None else keep.copy()
    order = order if keep.sum() >= _QUADRATIC_MIN_PAIRS else 1
    min_keep = 4 if order == 1 else _QUADRATIC_MIN_PAIRS

    def fit(mask):
        coef = _fit(pi[mask], qj[mask], centre, order)
        d2 = _pair_residuals2(coef, pi, qj, centre)
        return coef, d2, _robust_rms(d2[mask], 2 * len(coef))

    for _ in range(_REFINE_ITER):
        start = keep.copy()
        coef, d2, (rms_rob, rms) = fit(keep)
        while keep.sum() > min_keep:
            worst = np.flatnonzero(keep)[np.argmax(d2[keep])]
            trial = keep.copy()
            trial[worst] = False
            coef_t, d2_t, (rob_t, rms_t) = fit(trial)
            if d2_t[worst] <= max(_TRIM_RMS * rob_t, floor) ** 2:
                break
            keep, coef, d2, rms_rob, rms = trial, coef_t, d2_t, rob_t, rms_t
        keep = d2 <= max(_TRIM_RMS * rms_rob, floor) ** 2
        if keep.sum() < 3:
            keep = start
            break
        if (keep == start).all():
            break
    coef, d2, (rms_rob, rms) = fit(keep)
    return coef, keep, rms_rob, rms


def _refine(i, j, p, q, centre, order, inliers):
    """Local optimisation: robust refit on the inliers and re-selection until stable.

    With ``order=None``, when the affine map is chosen, the quadratic map
    fitted to its inliers is tried as well: it is taken when it brings more
    points within the tolerance and an F-test prefers it on those.
    ``inliers`` is the :class:`_Inliers` of the search.
    Returns the inliers (i, j), their squared residuals and robust rms.
    """
    floor = _TRIM_FLOOR * np.sqrt(inliers.tau2)
    d2 = None

    current = None
    for _ in range(_REFINE_ITER):
        if len(i) < 3:
            return None
        coef = _robust_fit(p, q, i, j, centre, order, floor)[0]
        i, j, d2 = inliers.of_map(coef, q, centre)
        if order is None and len(coef) == 3 and len(i) >= _QUADRATIC_MIN_PAIRS:
            coef_q = _eliminate(p[i], q[j], centre, 2, floor)[0]
            iq, jq, d2q = inliers.of_map(coef_q, q, centre)
            if len(iq) > len(i) and _choose_order(p[iq], q[jq], centre, None) == 2:
                i, j, d2 = iq, jq, d2q
        key = (tuple(i), tuple(j))
        if key == current:
            break
        current = key
    if len(i) < 3:
        return None
    return i, j, d2, _robust_rms(d2, 2 * len(coef))[0]


def _search(p, q, parity, tau2, colours, order, rng, bound):
    """Best inlier correspondences (i, j) of the automatic search, and the hypothesis count."""
    colour_ok = colours.ok
    mags = None if colours.mag1 is None else (colours.mag1, colours.mag2)
    a, b = _hypotheses(p, q, parity, rng, mags, bound)
    n_hyp = len(a)
    if n_hyp == 0:
        return None, 0
    inliers = _Inliers(p, tau2, colour_ok)
    counts, score = inliers.score(a, b, q)
    rank = np.argsort(-score, kind="stable")
    centre = q.mean(axis=0)
    refined = []
    seen = set()
    tried = 0
    for h in rank:
        if tried >= _N_REFINE:
            break
        if counts[h] < 3:
            continue
        coef = np.vstack([b[h] + a[h] @ centre, a[h].T])
        i, j, _ = inliers.of_map(coef, q, centre)
        key = (tuple(i), tuple(j))
        if key in seen:
            continue
        seen.add(key)
        tried += 1
        res = _refine(i, j, p, q, centre, order, inliers)
        if res is not None:
            refined.append(res)
    if not refined:
        return None, n_hyp
    # compare the refined hypotheses by their MSAC score at a selection
    # scale: 4 times the smallest robust rms among those with nearly the most
    # inliers, between half and all of the tolerance (a precise solution beats
    # a loose one with as many inliers)
    most = max(len(r[0]) for r in refined)
    rms_min = min(r[3] for r in refined if len(r[0]) >= most - 1)
    sel2 = np.clip(_SELECT_RMS * rms_min, _SELECT_FRACTION * np.sqrt(tau2), np.sqrt(tau2)) ** 2
    scores = [np.maximum(1.0 - r[2] / sel2, 0.0).sum() for r in refined]
    best = refined[int(np.argmax(scores))]
    return best, n_hyp


# ---------------------------------------------------------------------------
# assignment and confidence
# ---------------------------------------------------------------------------


def _assign(allowed, cost):
    """One-to-one pairs minimising the total cost; unmatched points cost 0.5 each.

    ``cost`` is scaled so that a pair at the gate costs about 1: a pair is
    preferred to leaving both of its points unmatched when its cost is < 1.
    """
    n1, n2 = cost.shape
    big = 1e6
    top = np.full((n1, n2 + n1), big)
    top[:, :n2] = np.where(allowed, cost, big)
    top[np.arange(n1), n2 + np.arange(n1)] = 0.5
    bottom = np.full((n2, n2 + n1), big)
    bottom[np.arange(n2), np.arange(n2)] = 0.5
    bottom[:, n2:] = 0.0
    rows, cols = linear_sum_assignment(np.vstack([top, bottom]))
    sel = (rows < n1) & (cols < n2)
    i, j = rows[sel], cols[sel]
    keep = allowed[i, j]
    return i[keep], j[keep]


def _confidence(chi2, i, j):
    """Posterior probability of each chosen pair against its alternatives.

    Every other candidate of either member (same row or column of ``chi2``)
    competes with weight exp(-(chi2_alt - chi2_pair) / 2).
    """
    conf = np.empty(len(i))
    for k, (a, b) in enumerate(zip(i, j, strict=True)):
        best = chi2[a, b]
        alt = np.concatenate([np.delete(chi2[a, :], b), np.delete(chi2[:, b], a)])
        delta = np.clip(alt - best, -700.0, 700.0)
        conf[k] = 1.0 / (1.0 + np.exp(-0.5 * delta).sum())
    return conf


def _robust_rms(d2, n_params):
    """rms of the metric residuals from their median, corrected for the fitted parameters.

    For Gaussian noise the residual length is Rayleigh distributed and
    rms = 1.2011 * median; the factor sqrt(2n / (2n - n_params)) undoes the
    shrinkage by the fit.
    """
    n = len(d2)
    dof = max(2 * n - n_params, 1)
    med = np.median(np.sqrt(d2))
    rms = np.sqrt(np.mean(d2) * 2 * n / dof)
    return 1.2011 * med * np.sqrt(2 * n / dof), rms


# ---------------------------------------------------------------------------
# public functions
# ---------------------------------------------------------------------------


def _pairs_table(id_pairs, ids1, ids2, p, q, sky1, sky2, i, j):
    """The common columns of a pairs table: ids and positions of the pairs (i, j).

    ``pair_id`` comes from ``id_pairs`` when it is a table with that column,
    otherwise it counts from 1.
    """
    out = QTable()
    if isinstance(id_pairs, Table) and PAIR_ID in id_pairs.colnames:
        check_unique_pair_ids(id_pairs, "the id pairs given")
        out[PAIR_ID] = np.asarray(id_pairs[PAIR_ID])
    else:
        out[PAIR_ID] = np.arange(1, len(i) + 1)
    out[ID_COLUMNS[0]] = ids1[i]
    out[ID_COLUMNS[1]] = ids2[j]
    for (x, y), xy in ((xy_cols(1), p[i]), (xy_cols(2), q[j])):
        out[x] = xy[:, 0] * u.arcsec
        out[y] = xy[:, 1] * u.arcsec
    if sky1 is not None:
        out[SKY_COLUMNS[0]] = sky1[i]
        out[SKY_COLUMNS[1]] = sky2[j]
    return out


@dataclass(frozen=True)
class _MapFit:
    """A fitted arc-to-arc map and its residuals (shared by manual and automatic pairing).

    ``coef`` (K, 2) are the map coefficients about ``centre`` (see
    :func:`_features`), ``d2`` the (N1, N2) squared metric residuals of every
    combination, ``rms_robust`` and ``rms`` those of the pairs (arcsec).
    """

    coef: np.ndarray
    centre: np.ndarray
    d2: np.ndarray
    rms_robust: float
    rms: float

    def meta(self):
        """``meta['map']`` of the pairs table: A, offset, centre, parity, det, rms, order."""
        coef, centre = self.coef, self.centre
        a_mat = coef[1:3].T.copy()
        det = float(np.linalg.det(a_mat))
        offset = coef[0] - a_mat @ centre
        return {
            "A": a_mat,
            "offset": offset * u.arcsec,
            "centre": centre * u.arcsec,
            "parity": int(np.sign(det)),
            "det": det,
            "rms": self.rms * u.arcsec,
            "rms_robust": self.rms_robust * u.arcsec,
            "order": 2 if len(coef) == 6 else 1,
            "quadratic": coef[3:].copy() / u.arcsec if len(coef) == 6 else None,
        }


@dataclass(frozen=True)
class _Pairing:
    """The pairs (i, j) of a pairing, its map and its bookkeeping (for ``meta``)."""

    i: np.ndarray
    j: np.ndarray
    fit: _MapFit
    n_hypotheses: int
    n_inliers: int
    max_residual: float | None


@dataclass(frozen=True)
class _Colours:
    """Colour evidence of all combinations (catalogue 1 rows x catalogue 2 columns).

    ``chi2`` (N1, N2) of the colour differences (zeros without flux columns),
    ``diff`` the largest colour difference and ``ok`` the colour gate (None
    without flux columns), ``mag1`` and ``mag2`` the mean magnitudes of the
    points (None without flux columns).
    """

    chi2: np.ndarray
    diff: np.ndarray | None = None
    ok: np.ndarray | None = None
    mag1: np.ndarray | None = None
    mag2: np.ndarray | None = None


def _colour_terms(catalog1, catalog2, cols, csig, n1, n2):
    """The :class:`_Colours` of two catalogues for the flux columns ``cols`` (or None)."""
    if cols is None:
        return _Colours(np.zeros((n1, n2)))
    units = [None] * len(cols)
    col1, mag1 = _colours(catalog1, cols, "catalog1", units)
    col2, mag2 = _colours(catalog2, cols, "catalog2", units)
    dcol = col1[:, None, :] - col2[None, :, :]  # (N1, N2, K-1)
    dcol = np.where(np.isfinite(dcol), dcol, 0.0)
    colour_chi2 = (dcol**2).sum(axis=2) / csig**2
    colour_diff = np.abs(dcol).max(axis=2)
    return _Colours(colour_chi2, colour_diff, colour_diff <= _COLOUR_GATE * csig, mag1, mag2)


def _tolerances(p, q, tolerance):
    """(inlier tolerance, cap of the residual gate) in arcsec."""
    nn1 = cKDTree(p).query(p, k=2)[0][:, 1]
    nn2 = cKDTree(q).query(q, k=2)[0][:, 1]
    nn = min(np.median(nn1), np.median(nn2))
    if tolerance is None:
        tol = _TOLERANCE_FRACTION * nn
    else:
        tol = as_angle_scalar(tolerance, "tolerance", allow_zero=False)
    return tol, max(tol, _GATE_CAP * nn)


def _manual_pairing(ids, ids1, ids2, p, q, centre, order, max_residual):
    """The map fitted to a manual list of id pairs."""
    id1, id2 = _id_pairs(ids, "ids")
    i = _rows_of(ids1, id1, "ids", "catalog1")
    j = _rows_of(ids2, id2, "ids", "catalog2")
    if len(i) < 3:
        raise ValueError(f"ids must give at least 3 pairs to fit the map, got {len(i)}")
    if max_residual is not None:
        as_angle_scalar(max_residual, "max_residual", allow_zero=False)
    coef = _fit(p[i], q[j], centre, _choose_order(p[i], q[j], centre, order))
    d2_all = _residuals2(coef, p, q, centre)
    rms_rob, rms = _robust_rms(d2_all[i, j], 2 * len(coef))
    fit = _MapFit(coef, centre, d2_all, rms_rob, rms)
    return _Pairing(i, j, fit, n_hypotheses=0, n_inliers=len(i), max_residual=None)


def _crowded(n_pairs, n1, n2):
    """Whether a pairing leaves most points of the larger catalogue unmatched."""
    return 2 * n_pairs < max(n1, n2)


def _robust_area(p):
    """Area (arcsec^2) of the convex hull of the points within their 1-99 % quantile
    box widened by 10 % (a stray detection far away does not count), and how many
    points it holds; (0, 0) when the points span no area."""
    lo, hi = _pairing_kernels.quantile_box(p)
    inside = np.all((p >= lo) & (p <= hi), axis=1)
    try:
        return ConvexHull(p[inside]).volume, int(inside.sum())
    except QhullError:  # collinear or too few points
        return 0.0, 0


def _chance_gate2(coef, p, q, centre, rms_rob, n_pairs, colour_ok, gate2):
    """The squared gates ``gate2`` (N2,), narrowed to where a chance coincidence is likelier.

    A true pair's L1 position scatters about the mapped L2 one as a Gaussian
    of per-axis variance ``s2 = rms_rob^2 / 2`` in the metric, plus a tail: a
    fraction ``_TAIL_FRACTION`` of true pairs spread evenly over the gate
    (map misfit, centroid outliers). The ellipse ``d < g`` covers
    ``pi g^2 sqrt(det C)`` arcsec^2 of arc L1. A chance coincidence is a
    point of catalogue 1 without counterpart, of density ``rho`` (those
    points over the area of the convex hull of catalogue 1) with compatible
    colours (the fraction ``f`` of combinations that pass the colour gate).
    Only in a crowded pairing (:func:`_crowded`; the hull and its points are
    those of :func:`_robust_area`).
    With the prior fraction ``pi_t = n_pairs / N2`` of true pairs: where the
    tail alone is denser than chance, the gate stays; elsewhere a pair is
    likelier true than chance while
    ``d^2 < 2 s2 ln(pi_t / (2 pi s2 sqrt(det C) rho f))``, never below
    ``_CHANCE_GATE_FLOOR`` standard deviations.
    """
    n1, n2 = len(p), len(q)
    if not _crowded(n_pairs, n1, n2):
        return gate2
    s2 = max(rms_rob, 1e-12) ** 2 / 2.0
    area, n_in = _robust_area(p)
    if not area > 0:  # no area: no chance density
        return gate2
    chance = max(n_in - n_pairs, 0.5) / area
    if colour_ok is not None:
        chance *= max(float(colour_ok.mean()), 1.0 / colour_ok.size)
    jac = _jacobians(coef, q, centre)
    sqrt_det = np.sqrt(np.linalg.det(0.5 * (np.eye(2) + jac @ np.swapaxes(jac, 1, 2))))
    prior = min(max(n_pairs, 1) / n2, 1.0)
    tail = _TAIL_FRACTION * prior / (np.pi * gate2 * sqrt_det)
    log_ratio = np.log(prior / (2.0 * np.pi * s2 * sqrt_det * chance))
    narrow = 2.0 * s2 * np.maximum(log_ratio, 0.5 * _CHANCE_GATE_FLOOR**2)
    return np.where(tail >= chance, gate2, np.minimum(gate2, narrow))


def _decoy_inliers(p, q, parity, tol, colours, order, rng, n_inliers, bound):
    """Most inliers the search finds on decoys of catalogue 2, or None when not needed.

    Run only in a crowded pairing (:func:`_crowded`), where a chance map
    may beat the true one. A decoy moves every point of catalogue 2 by 1-2 of its median
    nearest-neighbour distances in a random direction: the same numbers of
    points, spread and colours, but no constellation.
    """
    if not _crowded(n_inliers, len(p), len(q)):
        return None
    nn = np.median(cKDTree(q).query(q, k=2)[0][:, 1])
    best = 0
    for _ in range(_N_DECOYS):
        angle = rng.uniform(0.0, 2.0 * np.pi, len(q))
        step = nn * (1.0 + rng.random(len(q)))
        decoy = q + step[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
        res, _ = _search(p, decoy, parity, tol**2, colours, order, rng, bound)
        best = max(best, 0 if res is None else len(res[0]))
    return best


def _bound_hint(bound):
    return (f". Only maps with |det A| between 1/{bound:g} and {bound:g}, stretched less than "
            f"{bound:g} times, are searched: if the arcs' magnifications differ more, give "
            "max_magnification ([pairing] max_magnification of a run configuration)")


def _automatic_pairing(p, q, centre, *, parity, order, tol, cap, max_residual, colours, rng,
                       bound):
    """Search for the map, then assign the pairs one to one along it (twice)."""
    colour_chi2, colour_ok = colours.chi2, colours.ok
    n2 = len(q)
    maxres_user = None if max_residual is None else as_angle_scalar(
        max_residual, "max_residual", allow_zero=False)
    best, n_hyp = _search(p, q, parity, tol**2, colours, order, rng, bound)
    if best is None or len(best[0]) < _MIN_AUTO_PAIRS:
        found = 0 if best is None else len(best[0])
        raise ValueError(
            "no map relates at least 4 points of catalog1 and catalog2 within the "
            f"tolerance {tol:.3g} arcsec (best: {found} points); check the catalogues, "
            "increase tolerance or pair manually with ids="
            + _bound_hint(bound)
        )
    i, j = best[0], best[1]
    n_inliers = len(i)
    n_decoy = _decoy_inliers(p, q, parity, tol, colours, order, rng, n_inliers, bound)
    if n_decoy is not None and n_inliers < _DECOY_MARGIN * n_decoy:
        raise ValueError(
            f"the best map brings {n_inliers} of the {len(q)} points of catalog2 onto "
            f"catalog1 ({len(p)} points), and the same search on a decoy (catalog2 with "
            f"its points scrambled) brings {n_decoy}: the pairing is not distinguishable "
            "from chance. Remove spurious candidates (e.g. by signal-to-noise), "
            + ("give flux_columns (colours, and the brightest points for the search), "
               if colour_ok is None else "")
            + "or pair manually with ids="
            + _bound_hint(bound)
        )
    for _ in range(2):
        coef, keep, rms_rob, rms = _robust_fit(p, q, i, j, centre, order, _TRIM_FLOOR * tol)
        if maxres_user is None:
            maxres = min(max(_MAX_RESIDUAL_RMS * rms_rob, _MAX_RESIDUAL_FLOOR * tol), cap)
        else:
            maxres = maxres_user
        d2_all = _residuals2(coef, p, q, centre)
        gate2 = np.full(n2, maxres**2)
        if maxres_user is None:
            # prediction interval: wider where the map extrapolates
            gate2 = np.minimum(gate2 * (1.0 + _leverage(coef, q, q[j[keep]], centre)), cap**2)
            # crowded catalogues: no wider than where a chance coincidence becomes likelier
            gate2 = _chance_gate2(coef, p, q, centre, rms_rob, len(i), colour_ok, gate2)
        allowed = d2_all <= gate2
        cost = d2_all / gate2
        if colour_ok is not None:
            allowed &= colour_ok
            cost = cost + colour_chi2 / (_COLOUR_GATE**2)
        i, j = _assign(allowed, cost)
        if len(i) < 3:
            raise ValueError(
                "the pairing collapsed to fewer than 3 pairs; increase max_residual or "
                "pair manually with ids="
            )
    # final map on the final pairs
    coef, keep, rms_rob, rms = _robust_fit(p, q, i, j, centre, order, _TRIM_FLOOR * tol)
    d2_all = _residuals2(coef, p, q, centre)
    rms = _robust_rms(d2_all[i, j], 2 * len(coef))[1]
    fit = _MapFit(coef, centre, d2_all, rms_rob, rms)
    return _Pairing(i, j, fit, n_hypotheses=n_hyp, n_inliers=n_inliers, max_residual=maxres)


def pair_constellations(
    catalog1,
    catalog2,
    *,
    ids=None,
    id_column="id",
    position_columns=("x", "y"),
    flux_columns=None,
    colour_sigma=0.1,
    tolerance=None,
    max_residual=None,
    order=None,
    parity=None,
    reference=None,
    seed=None,
    max_magnification=DEFAULT_MAX_MAGNIFICATION,
):
    """Pair the point sources of arc L1 with their counter-images on arc L2.

    Finds the map ``x1 = f(x2)`` (affine, ``A x2 + offset``, or with
    quadratic terms) that brings the most points of catalogue 2 onto points
    of catalogue 1, of either parity and any rotation, stretch and
    magnification, and pairs the points one to one along it. With ``ids``,
    takes a manual pairing instead: the map is fitted to the given pairs,
    which are returned with their residuals and confidences.

    Automatic pairing (``ids=None``), in short (see the "Pairing" page of the
    documentation for details and measured accuracy):

    1. *Hypotheses.* Every triangle of points of catalogue 2 (all of them up
       to 6000, else a random subset drawn with ``seed``) is described by the
       barycentric coordinates of the two other points nearest to its
       centroid, which any affine map preserves; it is matched to the
       ordered triangles of catalogue 1 (6 vertex orders each) with the
       nearest descriptors, and each match gives the affine map that is
       exact on its 3 points. Maps with ``|det A|`` outside 1/20-20, a
       stretch (ratio of singular values) above 20 or the wrong ``parity``
       are discarded. With ``flux_columns``, the triangles of the 24
       brightest points of each catalogue, described by each other only,
       give hypotheses as well (scored first): in a catalogue crowded with
       faint spurious detections, the bright points are mostly true sources.
    2. *Scoring.* Each map scores its inliers (mutual nearest neighbours
       closer than ``tolerance`` in the noise metric below, normalised to
       the same area for every map, with compatible colours) by MSAC, the
       sum of ``1 - d^2 / tolerance^2``.
    3. *Refinement.* The 24 best distinct hypotheses are refitted on their
       inliers by outlier-resistant least squares (backward elimination of
       pairs whose leave-one-out residual exceeds 4 robust rms) and their
       inliers re-selected until stable; a quadratic map is used where an
       F-test prefers it (p < 0.01, from 8 pairs on). The refined
       hypotheses are compared by their MSAC score at 4 times the smallest
       robust rms among them (between half and all of ``tolerance``).
    4. *Chance.* When the best map leaves most points of the larger
       catalogue unmatched, the search is repeated on two decoys of
       catalogue 2 (every point moved by 1-2 median nearest-neighbour
       distances in a random direction); the pairing is refused
       (``ValueError``) unless the map brings at least 1.3 times as many
       points onto catalogue 1 as the better decoy.
    5. *Assignment.* The map is refitted and the pairs assigned one to one
       with the Hungarian algorithm (`scipy.optimize.linear_sum_assignment`),
       minimising ``(d / gate)^2`` (plus ``(colour difference / (5
       colour_sigma))^2``), where leaving a point unmatched costs 0.5; a pair
       beyond its gate (or with a colour difference above 5
       ``colour_sigma``) is never formed. The gate is ``max_residual``,
       widened by ``sqrt(1 + leverage)`` where the map extrapolates, and
       narrowed in such a crowded catalogue to where a true pair (Gaussian
       residuals of the fitted rms) is likelier than a chance coincidence
       (the density of unmatched points of catalogue 1 with compatible
       colours). The map is refitted on the pairs and the assignment
       repeated once.

    Parameters
    ----------
    catalog1, catalog2 : `~astropy.table.Table` or `~astropy.units.Quantity`
        Detections on arc L1 and on arc L2 (e.g. from
        :func:`~lensdual.detection.find_point_sources`) or (N, 2) angle
        Quantities of positions; at least 3 points each, no two at the same
        position.
    ids : `~astropy.table.Table` or array-like, optional
        Manual pairing: a table with columns ``id1`` and ``id2`` (e.g. read
        from ECSV, or the output of this function; a ``pair_id`` column is
        kept) or an (M, 2) array of (id1, id2), at least 3 pairs. None
        (default): automatic pairing.
    id_column : str or None
        Column of catalogue ids (default ``"id"``); None, or a Quantity
        catalogue: the 0-based row numbers.
    position_columns : (str, str) or str
        The two columns of positions (angle Quantities, in one common
        tangent-plane frame), or the name of one SkyCoord column (e.g.
        ``"sky_centroid"``: both catalogues are projected onto the tangent
        plane at ``reference``, gnomonic, x west and y north, as
        :func:`~lensdual.photometry.measure_pairs` does) or of one (N, 2)
        angle column. Default ``("x", "y")``. Pixel positions must be
        converted to angles first.
    flux_columns : sequence of str, optional
        At least two flux columns present in both catalogues (e.g.
        ``["peak_F150W", "peak_F200W"]``): the colours
        ``-2.5 log10(f_k / f_0)`` of a pair agree (lensing is achromatic) and
        are used as extra evidence in the scoring, the assignment and the
        confidence. Non-positive or NaN fluxes mean "no colour".
    colour_sigma : float
        Standard deviation of the colour difference of a true pair, in mag
        (default 0.1).
    tolerance : `~astropy.units.Quantity`, optional
        Inlier distance of the search, in the noise metric. Default: 0.3
        times the smaller of the two catalogues' median nearest-neighbour
        distances.
    max_residual : `~astropy.units.Quantity`, optional
        Largest residual of a pair (automatic pairing; ignored with
        ``ids``). Default: 5 times the robust rms of the fitted pairs
        (1.2011 times their median residual, corrected for the fitted
        parameters), at least ``tolerance / 3`` and at most half the median
        nearest-neighbour distance (or ``tolerance``, if larger), widened
        by ``sqrt(1 + leverage)`` (up to the same limit) for points where
        the map extrapolates.
    order : {None, 1, 2}
        Map: 1 affine, 2 with quadratic terms (from 8 pairs on); None
        (default): chosen by an F-test.
    parity : {None, 1, -1}
        Only consider maps of this parity (``sign(det A)``; -1 for a fold
        pair). None (default): either.
    reference : `~astropy.coordinates.SkyCoord`, optional
        Tangent point for SkyCoord positions; default: the mean direction of
        all points of both catalogues.
    max_magnification : float
        The automatic search considers the maps with ``|det A|`` between
        ``1 / max_magnification`` and ``max_magnification`` whose stretch
        (ratio of the singular values of ``A``) is below it (default 20).
        Raise it for arcs whose magnifications differ more.
    seed : int, `numpy.random.Generator` or None
        Seed of the random subsets of triangles and hypotheses, drawn only
        for large catalogues (more than 6000 triangles or 30000
        hypotheses), and of the decoys (only when the best map leaves most
        points unmatched); the result is otherwise deterministic, and
        always is for a given seed.

    Returns
    -------
    pairs : `~astropy.table.QTable`
        One row per pair, by increasing ``id2`` (automatic) or in the order
        of ``ids``: ``pair_id`` (from 1), ``id1``, ``id2``, ``x1``, ``y1``,
        ``x2``, ``y2`` (arcsec), ``sky1`` and ``sky2`` for SkyCoord
        positions, ``residual`` and ``confidence``, plus ``colour_diff``
        (mag, the largest colour difference) with ``flux_columns``.

        ``residual`` (arcsec) is the offset of the L1 position from the
        mapped L2 position in the noise metric: ``sqrt(r^T C^-1 r)`` with
        ``r = x1 - f(x2)``, ``C = (I + J J^T) / 2`` and ``J`` the local
        Jacobian of the map, which weighs equal position errors on both arcs
        correctly (for a rotation it is the plain distance ``|r|``).
        ``confidence`` is the probability of the pair against every other
        partner of either of its points, for Gaussian residuals of the
        fitted rms and colour differences of ``colour_sigma``: 0.5 for a
        tie between two candidates, 1 for an unambiguous pair.

        ``meta``: ``map``, a dict with ``A`` ((2, 2) array), ``offset``,
        ``centre`` (arcsec), ``quadratic`` (None, or the (3, 2) array of
        the coefficients of ``dx^2, dx dy, dy^2`` in 1/arcsec, ``(dx, dy) =
        x2 - centre``) such that ``x1 = A x2 + offset + quadratic^T (dx^2,
        dx dy, dy^2)``; ``parity`` (+1 or -1), ``det``, ``order``, ``rms``
        and ``rms_robust`` (arcsec); ``method`` (``"automatic"`` or
        ``"manual"``), ``tolerance``, ``max_residual``, ``n_hypotheses``,
        ``n_inliers``, ``unmatched1`` and ``unmatched2`` (ids), and
        ``position_columns``, ``id_column``, ``flux_columns`` and
        ``reference`` (for :func:`pairs_from_ids` and the figure). As
        ``x1 ~ A x2 + offset``, ``A`` is the relative Jacobian of
        :ref:`pairs-table` and ``|det A|`` the size magnification of the
        constellation as a whole.

    Raises
    ------
    TypeError
        Positions without angular units, a catalogue of the wrong type.
    ValueError
        Fewer than 3 points in a catalogue, repeated positions or ids,
        unknown ids, no map relating at least 4 points, or a best map no
        better than on decoys ("not distinguishable from chance"; automatic
        pairing), bad parameters.

    See Also
    --------
    pairs_from_ids : the pairs table (with fluxes) of a list of id pairs.
    lensdual.visualization.plot_pairing_map : the pairing figure.

    Notes
    -----
    Automatic pairing needs at least 4 points with counterparts and works
    best from about 8. Points closer together than the position noise (in
    the direction the map compresses) cannot be told apart by their
    positions; colours may. Check pairs of low ``confidence`` by eye.

    Examples
    --------
    Ten points of arc L2 and their images on arc L1 under a rotated,
    stretched map, listed in the reverse order:

    >>> import numpy as np
    >>> import astropy.units as u
    >>> from lensdual.pairing import pair_constellations
    >>> x2 = np.random.default_rng(1).uniform(-5, 5, (10, 2))
    >>> x1 = x2 @ np.array([[0.0, 0.8], [-1.5, 0.3]]) + [20.0, 0.0]
    >>> pairs = pair_constellations(x1[::-1] * u.arcsec, x2 * u.arcsec, id_column=None)
    >>> pairs["id1"].tolist(), pairs["id2"].tolist()
    ([9, 8, 7, 6, 5, 4, 3, 2, 1, 0], [0, 1, 2, 3, 4, 5, 6, 7, 8, 9])
    >>> pairs.meta["map"]["A"].round(3)  # doctest: +FLOAT_CMP
    array([[ 0. , -1.5],
           [ 0.8,  0.3]])
    """
    if order is not None and (isinstance(order, bool) or order not in (1, 2)):
        raise ValueError(f"order must be None, 1 or 2, got {order!r}")
    if parity is not None and (isinstance(parity, bool) or parity not in (1, -1)):
        raise ValueError(f"parity must be None, 1 or -1, got {parity!r}")
    csig = as_real(colour_sigma, "colour_sigma", minimum=0.0, inclusive=False)
    bound = as_real(max_magnification, "max_magnification", minimum=1.0, inclusive=False)
    cols = _check_flux_columns(flux_columns)
    ids1, p, sky1, ids2, q, sky2, tangent = _catalogs(
        catalog1, catalog2, position_columns, id_column, reference)
    for name, xy in (("catalog1", p), ("catalog2", q)):
        if len(xy) < 3:
            raise ValueError(f"{name} must hold at least 3 positions, got {len(xy)}")
        check_unique_rows(xy, name)
    rng = np.random.default_rng(seed)
    colours = _colour_terms(catalog1, catalog2, cols, csig, len(p), len(q))
    colour_chi2, colour_diff = colours.chi2, colours.diff
    tol, cap = _tolerances(p, q, tolerance)
    centre = q.mean(axis=0)

    if ids is not None:
        method = "manual"
        pairing = _manual_pairing(ids, ids1, ids2, p, q, centre, order, max_residual)
    else:
        method = "automatic"
        pairing = _automatic_pairing(p, q, centre, parity=parity, order=order, tol=tol,
                                     cap=cap, max_residual=max_residual, colours=colours,
                                     rng=rng, bound=bound)
    fit = pairing.fit

    # confidence: chi-square of every combination
    sigma2 = max(fit.rms_robust, 1e-3 * tol) ** 2 / 2.0  # per-axis variance of the metric residual
    conf = _confidence(fit.d2 / sigma2 + colour_chi2, pairing.i, pairing.j)

    sort = np.argsort(pairing.j, kind="stable") if method == "automatic" else np.arange(len(conf))
    i, j, conf = pairing.i[sort], pairing.j[sort], conf[sort]

    out = _pairs_table(ids if method == "manual" else None, ids1, ids2, p, q, sky1, sky2, i, j)
    out["residual"] = np.sqrt(fit.d2[i, j]) * u.arcsec
    out["confidence"] = conf
    if colour_diff is not None:
        out["colour_diff"] = colour_diff[i, j] * u.mag
    maxres = pairing.max_residual
    out.meta["map"] = fit.meta()
    out.meta["method"] = method
    out.meta["tolerance"] = tol * u.arcsec
    out.meta["max_residual"] = None if maxres is None else maxres * u.arcsec
    out.meta["n_hypotheses"] = int(pairing.n_hypotheses)
    out.meta["n_inliers"] = int(pairing.n_inliers)
    out.meta["unmatched1"] = np.delete(ids1, i).tolist()
    out.meta["unmatched2"] = np.delete(ids2, j).tolist()
    out.meta["position_columns"] = (
        position_columns if isinstance(position_columns, str) else list(position_columns))
    out.meta["id_column"] = id_column
    out.meta["flux_columns"] = cols
    out.meta["reference"] = tangent
    return out

def pairs_from_ids(
    catalog1,
    catalog2,
    id_pairs,
    *,
    id_column="id",
    position_columns=("x", "y"),
    bands=None,
    flux_columns="flux_{band}",
    flux_err_columns="flux_err_{band}",
    reference=None,
):
    """The pairs table of a manual pairing, from two detection catalogues.

    This is how the paper paired its constellation: by eye, as a list of
    (id on L1, id on L2).

    Parameters
    ----------
    catalog1, catalog2 : `~astropy.table.Table` or `~astropy.units.Quantity`
        Detections on arc L1 and on arc L2, or (N, 2) angle Quantities of
        positions (then the ids are the 0-based row numbers and there are no
        fluxes).
    id_pairs : `~astropy.table.Table` or array-like
        A table with columns ``id1`` and ``id2`` (or exactly two columns; e.g.
        ``Table.read("pairs.ecsv")``, or the output of
        :func:`pair_constellations`) or an (M, 2) array of (id1, id2). A
        ``pair_id`` column is kept, else the pairs are numbered from 1 in the
        given order.
    id_column : str or None
        Column of catalogue ids (default ``"id"``); None: the 0-based row
        numbers.
    position_columns : (str, str) or str
        As in :func:`pair_constellations`.
    bands : sequence of str, optional
        Bands whose fluxes are copied. Default: ``catalog1.meta['bands']``
        when present, else none.
    flux_columns, flux_err_columns : str
        Templates of the catalogue columns of flux and flux error, formatted
        with ``band`` (defaults ``"flux_{band}"`` and ``"flux_err_{band}"``;
        the detection catalogues of
        :func:`~lensdual.detection.find_point_sources` have peak values
        ``"peak_{band}"`` and no errors). Error columns are copied when both
        catalogues have them.
    reference : `~astropy.coordinates.SkyCoord`, optional
        As in :func:`pair_constellations`.

    Returns
    -------
    pairs : `~astropy.table.QTable`
        The pairs table (:ref:`pairs-table`): ``pair_id``, ``id1``, ``id2``,
        ``x1``, ``y1``, ``x2``, ``y2`` (arcsec), ``sky1``, ``sky2`` for
        SkyCoord positions, ``flux1_<band>``, ``flux2_<band>`` and, when
        available, ``flux_err1_<band>``, ``flux_err2_<band>``;
        ``meta['bands']``, and ``meta['reference']``, the tangent point of
        SkyCoord positions (None otherwise; the ``reference`` of
        :func:`~lensdual.photometry.measure_pairs`).

    Raises
    ------
    TypeError
        Positions without angular units.
    ValueError
        Ids not found in their catalogue, or an id in more than one pair;
        missing columns.

    Examples
    --------
    >>> import astropy.units as u
    >>> from astropy.table import QTable
    >>> from lensdual.pairing import pairs_from_ids
    >>> cat1 = QTable({"id": [1, 2, 3], "x": [0.0, 1.0, 2.0] * u.arcsec,
    ...                "y": [0.0, 1.0, 0.0] * u.arcsec, "flux_F150W": [10.0, 20.0, 30.0]})
    >>> cat2 = QTable({"id": [11, 12, 13], "x": [9.0, 8.0, 7.0] * u.arcsec,
    ...                "y": [0.0, 2.0, 0.0] * u.arcsec, "flux_F150W": [5.0, 9.0, 16.0]})
    >>> pairs = pairs_from_ids(cat1, cat2, [(1, 13), (3, 11)], bands=["F150W"])
    >>> pairs["pair_id"].tolist(), pairs["id2"].tolist(), pairs["flux2_F150W"].tolist()
    ([1, 2], [13, 11], [16.0, 5.0])
    >>> pairs["x2"]
    <Quantity [7., 9.] arcsec>
    """
    ids1, p, sky1, ids2, q, sky2, tangent = _catalogs(
        catalog1, catalog2, position_columns, id_column, reference)
    id1, id2 = _id_pairs(id_pairs, "id_pairs")
    i = _rows_of(ids1, id1, "id_pairs", "catalog1")
    j = _rows_of(ids2, id2, "id_pairs", "catalog2")
    if bands is None:
        bands = catalog1.meta.get("bands", []) if isinstance(catalog1, Table) else []
    bands = [bands] if isinstance(bands, str) else list(bands)
    if bands and not (isinstance(catalog1, Table) and isinstance(catalog2, Table)):
        raise ValueError("bands needs catalog1 and catalog2 to be tables with flux columns")
    for template, name in ((flux_columns, "flux_columns"),
                           (flux_err_columns, "flux_err_columns")):
        if not isinstance(template, str) or "{band}" not in template:
            raise ValueError(f"{name} must be a template containing '{{band}}', got {template!r}")

    out = _pairs_table(id_pairs, ids1, ids2, p, q, sky1, sky2, i, j)
    for band in bands:
        fcol = flux_columns.format(band=band)
        ecol = flux_err_columns.format(band=band)
        for cat, name in ((catalog1, "catalog1"), (catalog2, "catalog2")):
            if fcol not in cat.colnames:
                raise ValueError(f"{name} has no flux column {fcol!r} of band {band!r}")
        out[flux_col(1, band)] = catalog1[fcol][i]
        out[flux_col(2, band)] = catalog2[fcol][j]
        if ecol in catalog1.colnames and ecol in catalog2.colnames:
            out[flux_err_col(1, band)] = catalog1[ecol][i]
            out[flux_err_col(2, band)] = catalog2[ecol][j]
    out.meta["bands"] = bands
    out.meta["position_columns"] = (
        position_columns if isinstance(position_columns, str) else list(position_columns))
    out.meta["id_column"] = id_column
    out.meta["reference"] = tangent
    return out

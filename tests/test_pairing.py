"""Tests of lensdual.pairing (pairing the point sources of two arcs) and its figure."""

import warnings

import matplotlib
import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.table import QTable, Table

from lensdual.exceptions import LensdualWarning
from lensdual.pairing import pair_constellations, pairs_from_ids

matplotlib.use("agg")


# ---------------------------------------------------------------------------
# synthetic constellations
# ---------------------------------------------------------------------------


def rotation(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s], [s, c]])


def random_map(rng, det_range=(0.3, 3.0), stretch_range=(1.0, 8.0), parity=None):
    """A random 2x2 matrix: |det| log-uniform in det_range, random rotations, the ratio
    of its singular values (stretch) uniform in stretch_range, parity random or given."""
    det = np.exp(rng.uniform(*np.log(det_range)))
    stretch = rng.uniform(*stretch_range)
    par = rng.choice([-1, 1]) if parity is None else parity
    diag = np.diag([np.sqrt(det * stretch), par * np.sqrt(det / stretch)])
    return rotation(rng.uniform(0, 2 * np.pi)) @ diag @ rotation(rng.uniform(0, 2 * np.pi))


def make_system(seed, m=12, unmatched=0.2, noise=0.005, quad=0.0, **map_kwargs):
    """Two catalogues of a constellation of ``m`` sources, related by a random map.

    A fraction ``unmatched`` of each catalogue has no counterpart: half of them
    are sources imaged on one arc only, half spurious detections drawn from
    the distribution of the real ones. Sources: an anisotropic Gaussian of
    1 arcsec (median nearest-neighbour distance ~0.2 arcsec); position noise
    ``noise`` arcsec per coordinate on both arcs; ``quad`` adds a quadratic
    distortion before the linear map. Returns (positions 1, positions 2,
    truth {row1: row2}, A).
    """
    rng = np.random.default_rng(seed)
    n_un = int(round(unmatched / (1 - unmatched) * m))
    n_miss = (n_un + 1) // 2
    n_spur = n_un - n_miss
    n_src = m + 2 * n_miss
    src = (rng.normal(size=(n_src, 2)) * [1.0, rng.uniform(0.3, 1.0)]) @ rotation(
        rng.uniform(0, 2 * np.pi)).T
    a_mat = random_map(rng, **map_kwargs)
    warped = src
    if quad:
        d = src - src.mean(axis=0)
        terms = np.column_stack([d[:, 0] ** 2, d[:, 0] * d[:, 1], d[:, 1] ** 2])
        warped = src + quad * terms @ rng.normal(size=(3, 2))
    l1 = warped @ a_mat.T + rng.normal(scale=5, size=2) + rng.normal(scale=noise, size=src.shape)
    l2 = src + rng.normal(scale=noise, size=src.shape)
    in1 = np.r_[np.arange(m), m + np.arange(n_miss)]
    in2 = np.r_[np.arange(m), m + n_miss + np.arange(n_miss)]

    def spurious(x):
        return rng.multivariate_normal(x.mean(axis=0), np.cov(x.T), size=n_spur)

    c1 = np.vstack([l1[in1], spurious(l1[in1])])
    c2 = np.vstack([l2[in2], spurious(l2[in2])])
    p1, p2 = rng.permutation(len(c1)), rng.permutation(len(c2))
    inv1, inv2 = np.argsort(p1), np.argsort(p2)
    truth = {int(inv1[k]): int(inv2[k]) for k in range(m)}
    return c1[p1] * u.arcsec, c2[p2] * u.arcsec, truth, a_mat


def crowded_system(seed, n_spurious, m=24):
    """``make_system`` (no unmatched points) buried in uniform spurious candidates, with fluxes.

    Both catalogues are QTables (``x``, ``y`` in arcsec; fluxes ``f1`` and
    ``f2`` in two bands). True sources: L2 flux log-uniform 20-500 (units of
    the detection noise), colour N(0, 0.3) mag; on L1 the flux times
    ``|det A|`` with 5 % scatter, and 0.03 mag of colour noise per arc.
    Spurious candidates, drawn uniformly over each arc's bounding box widened
    by 10 %: flux from N(>f) ~ f^-1.5 above 5 (the detection threshold),
    colour N(0, 0.5) mag. Returns (table 1, table 2, truth {row1: row2}).
    """
    c1, c2, truth, a_mat = make_system(seed, m=m, unmatched=0.0)
    rng = np.random.default_rng(10_000 + seed)
    pairs = sorted(truth.items())  # source k: rows (r1, r2)
    source = ({r1: k for k, (r1, _) in enumerate(pairs)},
              {r2: k for k, (_, r2) in enumerate(pairs)})
    flux2 = np.exp(rng.uniform(np.log(20), np.log(500), m))
    colour = rng.normal(0, 0.3, m)
    det = abs(np.linalg.det(a_mat))
    cats = []
    for arc, c in ((1, c1.to_value(u.arcsec)), (2, c2.to_value(u.arcsec))):
        lo, hi = c.min(axis=0), c.max(axis=0)
        pad = 0.05 * (hi - lo)
        xy = np.vstack([c, rng.uniform(lo - pad, hi + pad, (n_spurious, 2))])
        k = np.array([source[arc - 1][r] for r in range(len(c))])
        f = flux2[k] * (det * (1 + rng.normal(0, 0.05, len(c))) if arc == 1 else 1.0)
        col = colour[k] + rng.normal(0, 0.03, len(c))
        band1 = np.r_[f, 5.0 * rng.random(n_spurious) ** (-1 / 1.5)]
        band2 = band1 * 10 ** (-0.4 * np.r_[col, rng.normal(0, 0.5, n_spurious)])
        cats.append(QTable({"x": xy[:, 0] * u.arcsec, "y": xy[:, 1] * u.arcsec,
                            "f1": band1, "f2": band2}))
    return cats[0], cats[1], truth


def score(result, truth):
    """(correct, wrong) pairs of a result with 0-based row ids."""
    found = dict(zip(np.asarray(result["id1"]).tolist(), np.asarray(result["id2"]).tolist(),
                     strict=True))
    correct = sum(truth.get(k) == v for k, v in found.items())
    return correct, len(found) - correct


# ---------------------------------------------------------------------------
# automatic pairing
# ---------------------------------------------------------------------------


def test_random_affine_maps_either_parity():
    """30 random maps (det +-0.3..3, stretch up to 8), 20 % unmatched points per catalogue."""
    n_true = n_correct = 0
    wrong = []
    for seed in range(30):
        c1, c2, truth, a_mat = make_system(seed)
        result = pair_constellations(c1, c2, id_column=None, seed=0)
        correct, bad = score(result, truth)
        n_true += len(truth)
        n_correct += correct
        wrong.append(bad)
        fitted = result.meta["map"]
        assert fitted["parity"] == np.sign(np.linalg.det(a_mat))
        assert fitted["det"] == pytest.approx(np.linalg.det(a_mat), rel=0.05)
        assert np.all((result["confidence"] >= 0) & (result["confidence"] <= 1))
        assert result.meta["method"] == "automatic"
    assert n_correct >= 0.95 * n_true
    assert max(wrong) <= 1
    assert sum(w == 0 for w in wrong) >= 25  # no wrong pair in most systems


@pytest.mark.parametrize("parity", [-1, 1])
@pytest.mark.parametrize("det", [0.3, 3.0])
def test_extreme_maps(parity, det):
    """The hardest corners: |det| 0.3 or 3 with a stretch of 6-8, both parities."""
    for seed in range(3):
        c1, c2, truth, a_mat = make_system(100 + seed, m=14, det_range=(det, det),
                                           stretch_range=(6.0, 8.0), parity=parity)
        result = pair_constellations(c1, c2, id_column=None)
        correct, bad = score(result, truth)
        assert correct >= len(truth) - 1
        assert bad <= 1
        assert result.meta["map"]["parity"] == parity
        assert abs(result.meta["map"]["det"]) == pytest.approx(det, rel=0.05)


def test_parity_restriction():
    c1, c2, truth, a_mat = make_system(7, parity=-1)
    result = pair_constellations(c1, c2, id_column=None, parity=-1)
    assert score(result, truth) == (len(truth), 0)
    # forcing the wrong parity finds at most a chance alignment of a few points,
    # which a decoy catalogue matches as well: refused, never returned as pairs
    with pytest.raises(ValueError, match="not distinguishable from chance"):
        pair_constellations(c1, c2, id_column=None, parity=1)


def _dense_inliers(qm, minv, p, tau2, colour_ok):
    """Plain numpy reference: mutual nearest neighbours over all (N1, N2) distances."""
    r = p[:, None, :] - qm[None, :, :]
    d2 = np.einsum("ijk,jkl,ijl->ij", r, minv, r)
    if colour_ok is not None:
        d2 = np.where(colour_ok, d2, np.inf)
    best_i = np.argmin(d2, axis=0)
    best_j = np.argmin(d2, axis=1)
    j = np.arange(len(qm))
    ok = (best_j[best_i] == j) & (d2[best_i, j] < tau2)
    return best_i[ok], j[ok], d2[best_i[ok], j[ok]]


@pytest.mark.parametrize("colours", [False, True])
def test_inlier_kernels_match_all_distances(colours):
    """The grid kernels of the search equal mutual nearest neighbours over all distances."""
    from lensdual import _pairing_kernels as kern
    from lensdual.pairing import _apply, _jacobians, _metric

    rng = np.random.default_rng(5)
    c1, c2, _ = crowded_system(3, 150)
    p = np.column_stack([c1["x"].value, c1["y"].value])
    q = np.column_stack([c2["x"].value, c2["y"].value])
    colour_ok = rng.random((len(p), len(q))) < 0.6 if colours else None
    tau2 = 0.03**2
    grid = kern.grid(p, np.sqrt(tau2))
    flag = np.ones((1, 1), bool) if colour_ok is None else colour_ok
    # affine hypotheses: the true map and random perturbations of it
    centre = q.mean(axis=0)
    truth_pairs = [(k, v) for k, v in sorted(make_system(3, m=24, unmatched=0.0)[2].items())]
    coef = np.linalg.lstsq(np.column_stack([np.ones(24), q[[v for _, v in truth_pairs]]]),
                           p[[k for k, _ in truth_pairs]], rcond=None)[0]
    a = coef[1:].T[None] * (1 + 0.05 * rng.normal(size=(40, 2, 2)))
    b = coef[0][None] + 0.02 * rng.normal(size=(40, 2))
    a[0], b[0] = coef[1:].T, coef[0]
    counts, scores = kern.score_hypotheses(a, b, q, tau2, p, *grid, flag, colours)
    for h in range(len(a)):
        qm = q @ a[h].T + b[h]
        minv = np.broadcast_to(_metric(a[h], normalise=True), (len(q), 2, 2))
        i, j, d2 = _dense_inliers(qm, minv, p, tau2, colour_ok)
        assert counts[h] == len(i)
        assert scores[h] == pytest.approx((1 - d2 / tau2).sum(), rel=1e-12, abs=1e-12)
    if not colours:  # the true map has the most inliers (random colour gates cut it)
        assert counts[0] >= 20 and counts.max() == counts[0]
    # a quadratic map about the centre: one metric per mapped point
    quad = np.vstack([coef[0] + centre @ coef[1:], coef[1:], 0.002 * rng.normal(size=(3, 2))])
    qm = np.ascontiguousarray(_apply(quad, q, centre))
    minv = np.ascontiguousarray(_metric(_jacobians(quad, q, centre), normalise=True))
    got = kern.mutual_inliers(qm, minv, tau2, p, *grid, flag, colours)
    want = _dense_inliers(qm, minv, p, tau2, colour_ok)
    assert len(want[0]) >= 5
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    np.testing.assert_allclose(got[2], want[2], rtol=1e-12)


def test_crowded_catalogues_without_colours_are_refused():
    """300 spurious candidates per arc for 24 true pairs, positions only: chance maps
    match as many points as the true one; the pairing says so instead of pairing."""
    c1, c2, _ = crowded_system(0, 300)
    with pytest.raises(ValueError, match="not distinguishable from chance.*flux_columns"):
        pair_constellations(c1, c2, id_column=None, seed=0)


def test_crowded_refusal_with_colours_does_not_ask_for_them():
    """300 spurious candidates per arc, colours given, seed 0 (the map is not found):
    refused, and the advice is to cut candidates or pair by hand, not to give colours."""
    c1, c2, _ = crowded_system(0, 300)
    with pytest.raises(ValueError, match="not distinguishable from chance") as info:
        pair_constellations(c1, c2, id_column=None, seed=0, flux_columns=["f1", "f2"])
    assert "flux_columns" not in str(info.value)
    assert "signal-to-noise" in str(info.value) and "ids=" in str(info.value)


def test_crowded_pairing_is_reproducible_for_a_seed():
    """Sampled triangles, hypotheses and decoys all come from ``seed``."""
    c1, c2, _ = crowded_system(1, 100)
    runs = [pair_constellations(c1, c2, id_column=None, seed=3, flux_columns=["f1", "f2"])
            for _ in range(2)]
    for name in ("id1", "id2", "residual", "confidence"):
        np.testing.assert_array_equal(np.asarray(runs[0][name]), np.asarray(runs[1][name]))
    assert runs[0].meta["n_hypotheses"] == runs[1].meta["n_hypotheses"]


def test_a_stray_detection_far_away_changes_nothing():
    """One candidate 1e4 arcsec away: the kernel's grid keeps its cells, the chance
    density is not diluted, the pairs are those without it."""
    from lensdual import _pairing_kernels as kern

    c1, c2, truth = crowded_system(0, 100)
    p = np.column_stack([c1["x"].value, c1["y"].value])
    stray = c1.copy()
    stray.add_row({"x": 1e4 * u.arcsec, "y": 1e4 * u.arcsec, "f1": 10.0, "f2": 10.0})
    p_stray = np.column_stack([stray["x"].value, stray["y"].value])
    assert kern.grid(p_stray, 0.03)[4] == pytest.approx(kern.grid(p, 0.03)[4], rel=0.05)
    kw = dict(id_column=None, seed=0, flux_columns=["f1", "f2"])
    ref = pair_constellations(c1, c2, **kw)
    got = pair_constellations(stray, c2, **kw)
    assert score(got, truth) == score(ref, truth)
    assert score(got, truth)[0] >= 22


def test_small_catalogue_against_a_crowded_one_is_refused():
    """5 points against 300: some map always passes through all 5; decoys do as well."""
    c1, c2, _ = crowded_system(1, 300)
    with pytest.raises(ValueError, match="not distinguishable from chance"):
        pair_constellations(c1, c2[:5], id_column=None, seed=0)


def test_crowded_catalogues_with_colours():
    """100 faint spurious candidates per arc with random colours: the brightest points
    give the hypotheses, colours and the chance density the pairs."""
    n_true = n_correct = n_wrong = 0
    for seed in range(3):
        c1, c2, truth = crowded_system(seed, 100)
        result = pair_constellations(c1, c2, id_column=None, seed=0, flux_columns=["f1", "f2"])
        correct, bad = score(result, truth)
        n_true += len(truth)
        n_correct += correct
        n_wrong += bad
    assert n_correct >= 0.95 * n_true
    assert n_wrong <= 6


def test_chance_gate_closed_form():
    """The gate where a chance coincidence becomes likelier than a true pair."""
    from scipy.spatial import ConvexHull

    from lensdual.pairing import _chance_gate2

    rng = np.random.default_rng(2)
    p = rng.uniform(0, 2, (400, 2))
    q = rng.uniform(0, 2, (400, 2))
    coef = np.vstack([[0.0, 0.0], rotation(0.7).T])  # a rotation: sqrt(det C) = 1
    rms, n_pairs = 0.004, 30
    gate2 = np.full(400, (5 * rms) ** 2)
    got = _chance_gate2(coef, p, q, q.mean(axis=0), rms, n_pairs, None, gate2)
    s2 = rms**2 / 2
    rho = (400 - n_pairs) / ConvexHull(p).volume
    want = 2 * s2 * np.log((n_pairs / 400) / (2 * np.pi * s2 * rho))
    assert 0.2 * (n_pairs / 400) / (np.pi * gate2[0]) < rho  # the tail does not protect
    np.testing.assert_allclose(got, want, rtol=1e-12)
    # half the combinations pass the colour gate: half the chance density
    half = np.zeros((400, 400), bool)
    half[:, ::2] = True
    got_c = _chance_gate2(coef, p, q, q.mean(axis=0), rms, n_pairs, half, gate2)
    np.testing.assert_allclose(got_c, want + 2 * s2 * np.log(2), rtol=1e-12)
    # never below the floor of 2 standard deviations per axis
    wide = _chance_gate2(coef, p, q, q.mean(axis=0), 0.1, n_pairs, None, np.full(400, 1.0))
    np.testing.assert_allclose(wide, 2 * (0.1**2 / 2) * 2.0, rtol=1e-12)
    # a sparse catalogue (30 of 40 points paired): the tail is denser than chance
    sparse = _chance_gate2(coef, p[:40], q[:40], q[:40].mean(axis=0), rms, 30, None,
                           gate2[:40])
    np.testing.assert_array_equal(sparse, gate2[:40])


def test_mildly_non_linear_map():
    """A quadratic distortion of ~10 % of the separations: the quadratic map takes it."""
    n_true = n_correct = n_wrong = n_quadratic = 0
    for seed in range(10):
        c1, c2, truth, _ = make_system(200 + seed, m=16, quad=0.02)
        result = pair_constellations(c1, c2, id_column=None)
        correct, bad = score(result, truth)
        n_true += len(truth)
        n_correct += correct
        n_wrong += bad
        n_quadratic += result.meta["map"]["order"] == 2
    assert n_correct >= 0.95 * n_true
    assert n_wrong <= 2
    assert n_quadratic >= 7


def test_deterministic_and_fast():
    c1, c2, truth, _ = make_system(3, m=24)  # 30 x 30 points
    import time

    start = time.perf_counter()
    first = pair_constellations(c1, c2, id_column=None, seed=5)
    elapsed = time.perf_counter() - start
    second = pair_constellations(c1, c2, id_column=None, seed=5)
    assert elapsed < 3.0  # ~0.2 s on a laptop core
    for name in first.colnames:
        np.testing.assert_array_equal(first[name], second[name])
    assert score(first, truth)[0] >= len(truth) - 1


def test_order_and_max_residual_options():
    c1, c2, truth, _ = make_system(11)
    affine = pair_constellations(c1, c2, id_column=None, order=1)
    assert affine.meta["map"]["order"] == 1
    assert affine.meta["map"]["quadratic"] is None
    quadratic = pair_constellations(c1, c2, id_column=None, order=2)
    assert quadratic.meta["map"]["order"] == 2
    assert quadratic.meta["map"]["quadratic"].shape == (3, 2)
    # a tiny max_residual keeps only the best pairs
    tight = pair_constellations(c1, c2, id_column=None, max_residual=0.01 * u.arcsec)
    assert 3 <= len(tight) < len(affine)
    assert np.all(tight["residual"] <= 0.01 * u.arcsec)


def test_map_reproduces_positions():
    c1, c2, truth, a_mat = make_system(12, noise=0.0)
    result = pair_constellations(c1, c2, id_column=None, order=1)
    fitted = result.meta["map"]
    np.testing.assert_allclose(fitted["A"], a_mat, atol=1e-9)
    x2 = np.column_stack([result["x2"].value, result["y2"].value])
    x1 = np.column_stack([result["x1"].value, result["y1"].value])
    np.testing.assert_allclose(x2 @ fitted["A"].T + fitted["offset"].value, x1, atol=1e-9)
    assert result["residual"].max() < 1e-9 * u.arcsec
    assert fitted["rms"] < 1e-9 * u.arcsec


def colour_catalogues(seed):
    """Catalogues with F150W/F200W fluxes and a decoy: a spurious L1 point right on
    the mapped position of a true L2 point, closer than its true counterpart, with
    another colour. Returns (table1, table2, truth, (row1, row2, decoy row))."""
    c1, c2, truth, _ = make_system(seed, m=12, noise=0.01)
    p, q = c1.value, c2.value
    rng = np.random.default_rng(seed)
    rows1 = np.array(sorted(truth))
    rows2 = np.array([truth[k] for k in rows1])
    design = np.column_stack([q[rows2], np.ones(len(rows2))])
    coef = np.linalg.lstsq(design, p[rows1], rcond=None)[0]
    i0, j0 = int(rows1[0]), int(rows2[0])
    decoy = np.r_[q[j0], 1.0] @ coef
    p = np.vstack([p, decoy])
    colour1 = rng.uniform(-0.3, 0.3, len(p))
    colour2 = rng.uniform(-0.3, 0.3, len(q))
    for a, b in truth.items():
        colour2[b] = colour1[a]
    colour1[-1] = colour1[i0] + 1.0  # the decoy is 1 mag redder
    tabs = []
    for xy, colour in ((p, colour1), (q, colour2)):
        f200 = rng.uniform(1, 10, len(xy))
        tabs.append(QTable({
            "id": np.arange(len(xy)),
            "x": xy[:, 0] * u.arcsec,
            "y": xy[:, 1] * u.arcsec,
            "peak_F150W": f200 * 10 ** (-0.4 * colour) * u.nJy,
            "peak_F200W": f200 * u.nJy,
        }))
    return tabs[0], tabs[1], truth, (i0, j0, len(p) - 1)


def test_colours_break_an_ambiguity():
    t1, t2, truth, (i0, j0, decoy) = colour_catalogues(3)
    plain = pair_constellations(t1, t2)
    row = plain[plain["id2"] == j0]
    assert row["id1"][0] == decoy  # geometry alone takes the closer decoy
    coloured = pair_constellations(t1, t2, flux_columns=["peak_F150W", "peak_F200W"])
    row = coloured[coloured["id2"] == j0]
    assert row["id1"][0] == i0
    assert score(coloured, truth) == (len(truth), 0)
    assert coloured["colour_diff"].unit == u.mag
    assert np.all(coloured["colour_diff"] < 1e-9 * u.mag)
    # a NaN or non-positive flux means "no colour", not an error
    t1["peak_F150W"][0] = np.nan * u.nJy
    t2["peak_F200W"][1] = 0 * u.nJy
    assert len(pair_constellations(t1, t2, flux_columns=["peak_F150W", "peak_F200W"])) > 0


def test_confidence_flags_a_tie():
    """Two L1 points equally close to one mapped L2 point: confidence ~ 0.5."""
    c1, c2, truth, _ = make_system(4, m=12, noise=0.002)
    result = pair_constellations(c1, c2, id_column=None)
    assert np.median(result["confidence"]) > 0.99
    fitted = result.meta["map"]
    p, q = c1.value.copy(), c2.value
    i0 = int(result["id1"][0])
    j0 = int(result["id2"][0])
    mapped = q[j0] @ fitted["A"].T + fitted["offset"].value
    step = 0.3 * fitted["rms_robust"].value
    p[i0] = mapped + [step, 0.0]
    p = np.vstack([p, mapped - [step, 0.0]])
    tied = pair_constellations(p * u.arcsec, c2, id_column=None)
    row = tied[tied["id2"] == j0]
    assert 0.4 < row["confidence"][0] < 0.75


def test_sky_positions():
    c1, c2, truth, _ = make_system(5)
    centre = SkyCoord(110.83 * u.deg, -73.45 * u.deg)

    def to_sky(xy):  # x west, y north
        return centre.spherical_offsets_by(-xy[:, 0], xy[:, 1])

    t1 = QTable({"id": np.arange(len(c1)) + 1, "sky_centroid": to_sky(c1)})
    t2 = QTable({"id": np.arange(len(c2)) + 1, "sky_centroid": to_sky(c2)})
    result = pair_constellations(t1, t2, position_columns="sky_centroid")
    shifted = {k + 1: v + 1 for k, v in truth.items()}
    assert score(result, shifted) == (len(truth), 0)
    assert isinstance(result["sky1"], SkyCoord)
    assert isinstance(result.meta["reference"], SkyCoord)
    # same frame with the reference given: positions about it, x west
    again = pair_constellations(t1, t2, position_columns="sky_centroid", reference=centre)
    k = int(again["id1"][0]) - 1
    assert again["x1"][0].value == pytest.approx(c1.value[k, 0], abs=1e-6)
    assert again["y1"][0].value == pytest.approx(c1.value[k, 1], abs=1e-6)


# ---------------------------------------------------------------------------
# the SMACS0723 analogue
# ---------------------------------------------------------------------------


def smacs_catalogues(seed, n_drop=2, n_spurious=2):
    """Shuffled catalogues of the SMACS0723 analogue's arcs with dropped and spurious points."""
    from lensdual.simulation import smacs0723_analog

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LensdualWarning)
        pairs = smacs0723_analog(seed=seed).constellation(seed=seed)
    rng = np.random.default_rng(1000 + seed)
    n = len(pairs)
    x1 = np.column_stack([pairs["x1"].value, pairs["y1"].value])
    x2 = np.column_stack([pairs["x2"].value, pairs["y2"].value])
    order = rng.permutation(n)
    keep1 = np.setdiff1d(np.arange(n), order[:n_drop])
    keep2 = np.setdiff1d(np.arange(n), order[n_drop:2 * n_drop])
    tables, sources = [], []
    for x, keep, arc in ((x1, keep1, "1"), (x2, keep2, "2")):
        spur = rng.uniform(x.min(axis=0), x.max(axis=0), size=(n_spurious, 2))
        xy = np.vstack([x[keep], spur])
        flux = {b: np.r_[pairs[f"flux{arc}_{b}"].value[keep],
                         rng.uniform(1, 10, n_spurious)] for b in pairs.meta["bands"]}
        src = np.r_[keep, -np.ones(n_spurious, dtype=int)]
        perm = rng.permutation(len(xy))
        tab = QTable({"id": np.arange(1, len(xy) + 1), "x": xy[perm, 0] * u.arcsec,
                      "y": xy[perm, 1] * u.arcsec})
        for b in pairs.meta["bands"]:
            tab[f"flux_{b}"] = flux[b][perm] * u.nJy
        tables.append(tab)
        sources.append(src[perm])
    truth = {}
    for r1, s in enumerate(sources[0]):
        hit = np.flatnonzero(sources[1] == s)
        if s >= 0 and hit.size:
            truth[r1 + 1] = int(hit[0]) + 1
    return tables[0], tables[1], truth, pairs


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_smacs0723_analogue(seed):
    t1, t2, truth, pairs = smacs_catalogues(seed)
    result = pair_constellations(t1, t2)
    assert score(result, truth) == (len(truth), 0)
    assert result.meta["map"]["parity"] == -1  # a fold pair
    assert result.meta["map"]["order"] == 2  # the arcs are curved
    # the map's |det A| is the constellation's mean size magnification
    assert abs(result.meta["map"]["det"]) == pytest.approx(np.median(pairs["mu_true"]), rel=0.3)
    with_colours = pair_constellations(t1, t2, flux_columns=["flux_F150W", "flux_F200W"])
    assert score(with_colours, truth) == (len(truth), 0)


# ---------------------------------------------------------------------------
# manual pairing
# ---------------------------------------------------------------------------


def test_manual_pairing_round_trip(tmp_path):
    t1, t2, truth, _ = colour_catalogues(8)
    t1["flux_err_F150W"] = 0.05 * t1["peak_F150W"]
    t2["flux_err_F150W"] = 0.05 * t2["peak_F150W"]
    t1.meta["bands"] = ["F150W", "F200W"]
    id_pairs = Table({"id1": sorted(truth), "id2": [truth[k] for k in sorted(truth)]})
    id_pairs.write(tmp_path / "pairs.ecsv")
    read = Table.read(tmp_path / "pairs.ecsv")

    manual = pair_constellations(t1, t2, ids=read)
    assert manual.meta["method"] == "manual"
    np.testing.assert_array_equal(manual["id1"], read["id1"])
    np.testing.assert_array_equal(manual["id2"], read["id2"])
    assert manual["residual"].max() < 0.05 * u.arcsec
    assert manual.meta["map"]["parity"] in (-1, 1)

    table = pairs_from_ids(t1, t2, read, flux_columns="peak_{band}")
    assert table.colnames[:7] == ["pair_id", "id1", "id2", "x1", "y1", "x2", "y2"]
    np.testing.assert_array_equal(table["pair_id"], np.arange(1, len(read) + 1))
    assert table.meta["bands"] == ["F150W", "F200W"]
    rows1 = np.asarray(read["id1"])
    np.testing.assert_array_equal(table["flux1_F150W"], t1["peak_F150W"][rows1])
    np.testing.assert_array_equal(table["flux_err1_F150W"], t1["flux_err_F150W"][rows1])
    assert "flux_err1_F200W" not in table.colnames  # no error columns in the catalogues
    assert table["x1"].unit == u.arcsec
    # an (M, 2) array works as well, and the output of the automatic pairing
    array = pairs_from_ids(t1, t2, np.column_stack([read["id1"], read["id2"]]), bands=[])
    np.testing.assert_array_equal(array["x2"], table["x2"])
    auto = pair_constellations(t1, t2, flux_columns=["peak_F150W", "peak_F200W"])
    from_auto = pairs_from_ids(t1, t2, auto, flux_columns="peak_{band}")
    np.testing.assert_array_equal(from_auto["pair_id"], auto["pair_id"])


# ---------------------------------------------------------------------------
# bad input
# ---------------------------------------------------------------------------


def test_bad_input():
    c1, c2, truth, _ = make_system(9)
    t1 = Table({"id": np.arange(len(c1)), "x": c1.value[:, 0], "y": c1.value[:, 1]})
    t2 = QTable({"id": np.arange(len(c2)), "x": c2[:, 0], "y": c2[:, 1]})
    with pytest.raises(TypeError, match="catalog1 column 'x' must be an angle Quantity"):
        pair_constellations(t1, t2)
    with pytest.raises(TypeError, match=r"catalog1 must be an astropy Table.*got ndarray"):
        pair_constellations(c1.value, c2, id_column=None)
    with pytest.raises(TypeError, match="catalog2 must be an astropy Table"):
        pair_constellations(c1, list(c2.value), id_column=None)
    with pytest.raises(ValueError, match="catalog2 must hold at least 3 positions"):
        pair_constellations(c1, c2[:2], id_column=None)
    with pytest.raises(ValueError, match="catalog1 contains duplicate positions"):
        pair_constellations(np.vstack([c1, c1[:1]]), c2, id_column=None)
    with pytest.raises(ValueError, match="catalog2 has no column 'ra'"):
        pair_constellations(c1, t2, id_column=None, position_columns=("ra", "dec"))
    with pytest.raises(TypeError, match="tolerance must be a scalar Quantity"):
        pair_constellations(c1, c2, id_column=None, tolerance=0.1)
    with pytest.raises(ValueError, match="order must be None, 1 or 2"):
        pair_constellations(c1, c2, id_column=None, order=3)
    with pytest.raises(ValueError, match="parity must be None, 1 or -1"):
        pair_constellations(c1, c2, id_column=None, parity=0)
    with pytest.raises(TypeError, match="flux_columns must be a sequence"):
        pair_constellations(t2, t2, flux_columns="x")
    with pytest.raises(ValueError, match="catalog1 has no flux column 'F150W'"):
        pair_constellations(t2, t2, flux_columns=["F150W", "F200W"])
    with pytest.raises(ValueError, match="colour_sigma must be > 0"):
        pair_constellations(c1, c2, id_column=None, colour_sigma=0)


def test_bad_ids():
    t1, t2, truth, _ = colour_catalogues(2)
    good = np.array([[k, truth[k]] for k in sorted(truth)])
    unknown = good.copy()
    unknown[1, 1] = 999
    with pytest.raises(ValueError, match=r"id\(s\) \[999\] not found in catalog2"):
        pair_constellations(t1, t2, ids=unknown)
    with pytest.raises(ValueError, match=r"id\(s\) \[999\] not found in catalog2"):
        pairs_from_ids(t1, t2, unknown)
    repeated = good.copy()
    repeated[1, 0] = repeated[0, 0]
    with pytest.raises(ValueError, match="catalog1 id.* appear in more than one pair"):
        pair_constellations(t1, t2, ids=repeated)
    with pytest.raises(ValueError, match="catalog1 id.* appear in more than one pair"):
        pairs_from_ids(t1, t2, repeated)
    with pytest.raises(ValueError, match="id_pairs must be a table with columns id1, id2"):
        pairs_from_ids(t1, t2, good[:, 0])
    with pytest.raises(ValueError, match="ids must give at least 3 pairs"):
        pair_constellations(t1, t2, ids=good[:2])
    t1["id"][1] = t1["id"][0]
    with pytest.raises(ValueError, match="catalog1 column 'id' has repeated id"):
        pairs_from_ids(t1, t2, good)
    with pytest.raises(ValueError, match="catalog1 has no id column 'label'"):
        pairs_from_ids(t1, t2, good, id_column="label")
    with pytest.raises(ValueError, match="flux_columns must be a template"):
        pairs_from_ids(t2, t2, good, bands=["F150W"], flux_columns="peak")


# ---------------------------------------------------------------------------
# the figure
# ---------------------------------------------------------------------------


def test_plot_pairing_map():
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    from lensdual.visualization import plot_pairing_map

    t1, t2, truth, _ = smacs_catalogues(0)
    result = pair_constellations(t1, t2)
    ax = plot_pairing_map(result, t1, t2)
    lines = [c for c in ax.collections if isinstance(c, LineCollection)]
    assert len(lines) == 1 and len(lines[0].get_segments()) == len(result)
    labels = {t.get_text() for t in ax.texts}
    assert labels == {str(k) for k in result["pair_id"]}
    assert "L1 (flipped and rotated)" in [t.get_text() for t in ax.get_legend().get_texts()]
    # the drawn L1 segments have the lengths of L1 (rotated and flipped, not scaled)
    seg = np.asarray(lines[0].get_segments())[:, 0, :]
    x1 = np.column_stack([result["x1"].value, result["y1"].value])
    np.testing.assert_allclose(np.linalg.norm(seg - seg[0], axis=1),
                               np.linalg.norm(x1 - x1[0], axis=1), atol=1e-12)
    # any pairs table works (the map is then fitted to its pairs), on a given axis
    fig, ax2 = plt.subplots()
    bare = QTable(result[["pair_id", "x1", "y1", "x2", "y2"]])
    assert plot_pairing_map(bare, ax=ax2, offset=[0.3, 0.0] * u.arcsec) is ax2
    plt.close("all")


def _magnified_catalogues(det, seed):
    """15 points on arc L2 and their images on L1 under a map of |det A| = ``det``."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(-0.5, 0.5, (15, 2))
    s = np.sqrt(det)
    p = q @ np.array([[s * 1.2, 0.3], [0.1, -s / 1.2]]).T + 0.002 * rng.standard_normal((15, 2))
    c1 = QTable({"id": np.arange(15), "x": p[:, 0] * u.arcsec, "y": p[:, 1] * u.arcsec})
    c2 = QTable({"id": np.arange(15), "x": q[:, 0] * u.arcsec, "y": q[:, 1] * u.arcsec})
    return c1, c2


@pytest.mark.parametrize("det", [30.0, 60.0])
def test_strongly_magnifying_maps_are_found(det):
    """|det A| of 30 and 60 (one arc much more magnified than the other): paired once
    max_magnification allows it."""
    c1, c2 = _magnified_catalogues(det, 1)
    pairs = pair_constellations(c1, c2, seed=0, max_magnification=100)
    assert len(pairs) == 15
    assert np.array_equal(np.asarray(pairs["id1"]), np.asarray(pairs["id2"]))


def test_a_map_beyond_max_magnification_is_named():
    c1, c2 = _magnified_catalogues(30.0, 1)
    with pytest.raises(ValueError, match="give max_magnification"):
        pair_constellations(c1, c2, seed=0)  # the default bound, 20
    with pytest.raises(ValueError, match="max_magnification"):
        pair_constellations(c1, c2, max_magnification=1.0)

"""Constellations from knot catalogues: pairing.pairs_from_knots, read_macro_images,
estimators.estimate_sigma_pos and parametric.compare_size_with_models."""

from pathlib import Path

import numpy as np
import pytest
from _lenstool_text import COSMOLOGY
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.table import QTable

from lensdual._frames import tangent_to_sky
from lensdual.estimators import estimate_sigma_pos, size_magnification
from lensdual.pairing import pairs_from_knots, read_macro_images

REF = SkyCoord(150.0 * u.deg, 2.0 * u.deg)
HFF = Path(__file__).parents[2] / "shared" / "data" / "hff_cats_lenstool"


def rotation(a):
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


# three macro-images of a knotty galaxy: affine images of one source-plane
# constellation, A at (-12, 0), B at (10, 2) (parity flipped), C at (0, 15)
MAPS = {
    "A": (np.array([-12.0, 0.0]), 2.0 * rotation(0.3)),
    "B": (np.array([10.0, 2.0]), np.diag([1.0, -1.0]) @ (1.5 * rotation(-0.5))),
    "C": (np.array([0.0, 15.0]), np.array([[3.0, 0.5], [0.0, 1.2]])),
}


def synthetic(n_knots=10, seed=0):
    """(catalogue rows {id: (x, y)}, centres {name: (x, y)}, source positions)."""
    rng = np.random.default_rng(seed)
    src = rng.uniform(-1.0, 1.0, (n_knots, 2))
    rows = {}
    for k, s in enumerate(src):
        for n, (c, a) in enumerate(MAPS.values(), start=1):
            rows[f"{100 + k}.{n}"] = c + a @ s
    return rows, {name: c for name, (c, _) in MAPS.items()}, src


def catalogue(rows):
    ids = list(rows)
    xy = np.array([rows[i] for i in ids])
    return QTable({"id": ids, "sky": tangent_to_sky(xy[:, 0], xy[:, 1], REF)})


def centres_sky(centres):
    return {n: tangent_to_sky(c[0], c[1], REF) for n, c in centres.items()}


def test_clean_catalogue_gives_every_pair_of_macro_images():
    rows, centres, src = synthetic()
    kp = pairs_from_knots(catalogue(rows), centres_sky(centres), reference=REF)
    assert list(kp.pairs) == [("A", "B"), ("A", "C"), ("B", "C")]
    assert (kp.images["status"] == "used").all()
    for (m1, m2), tab in kp.pairs.items():
        assert len(tab) == 10
        assert tab.meta["macro1"] == m1 and tab.meta["macro2"] == m2
        # positions reproduce the input frame (the reference is the tangent point)
        k = np.array([int(s) - 100 for s in tab["knot"]])
        c1, a1 = MAPS[m1]
        c2, a2 = MAPS[m2]
        np.testing.assert_allclose(tab["x1"].to_value(u.arcsec), (c1 + src[k] @ a1.T)[:, 0],
                                   atol=1e-8)
        np.testing.assert_allclose(tab["y2"].to_value(u.arcsec), (c2 + src[k] @ a2.T)[:, 1],
                                   atol=1e-8)
        # the relative Jacobian of an affine constellation is exact: mu_size = |det A1 / det A2|
        t1 = np.column_stack([tab["x1"], tab["y1"]])
        t2 = np.column_stack([tab["x2"], tab["y2"]])
        size = size_magnification(t1, t2, method="quad", n_bootstrap=10, seed=0,
                                  sigma_pos=1e-3 * u.arcsec)
        np.testing.assert_allclose(size["mu_size"], abs(np.linalg.det(a1) / np.linalg.det(a2)),
                                   rtol=1e-8)


def test_traps_extra_missing_swapped_single_and_ambiguous():
    rows, centres, _ = synthetic()
    # extra image: knot 102 has a second image on A (around a cluster member)
    rows["102.4"] = rows["102.1"] + [0.4, -0.3]
    # missing image: knot 103 is not seen on C
    del rows["103.3"]
    # swapped sub-indices: knot 104's images on A and B are numbered the other way
    rows["104.1"], rows["104.2"] = rows["104.2"], rows["104.1"]
    # a knot seen only once
    rows["150.1"] = np.array([-12.5, 0.5])
    # an image half-way between A and B
    rows["151.1"] = np.array([-1.0, 1.0])
    rows["151.2"] = rows["105.3"] + [0.2, 0.2]
    kp = pairs_from_knots(catalogue(rows), centres_sky(centres), reference=REF)
    status = dict(zip(kp.images["id"], kp.images["status"], strict=True))
    assert status["102.1"] == status["102.4"] == "extra"
    assert status["102.2"] == status["102.3"] == "used"
    assert status["150.1"] == "single"
    assert status["151.1"] == "ambiguous" and status["151.2"] == "single"
    assert status["103.1"] == status["103.2"] == "used"
    knots = {key: set(tab["knot"]) for key, tab in kp.pairs.items()}
    assert "102" not in knots[("A", "B")] and "102" in knots[("B", "C")]
    assert "103" in knots[("A", "B")] and "103" not in knots[("A", "C")]
    # the swapped knot is paired by position, not by sub-index
    ab = kp.pairs[("A", "B")]
    row = list(ab["knot"]).index("104")
    assert ab["id1"][row] == "104.2" and ab["id2"][row] == "104.1"
    assert {"150", "151"}.isdisjoint(set().union(*knots.values()))
    text = kp.summary()
    assert "extra (2): 102.1, 102.4" in text and "ambiguous (1): 151.1" in text
    assert len(kp.dropped()) == 5


def test_mapping_and_max_distance():
    rows, centres, _ = synthetic(n_knots=6)
    cat = catalogue(rows)
    names = {"1": "A", "2": "B", "3": "C"}
    mapping = {i: names[i.split(".")[1]] for i in rows}
    del mapping["101.3"]
    kp = pairs_from_knots(cat, ["A", "B", "C"], mapping=mapping)
    assert kp.assign == "mapping"
    status = dict(zip(kp.images["id"], kp.images["status"], strict=True))
    assert status["101.3"] == "unassigned"
    assert len(kp.pairs[("A", "B")]) == 6 and len(kp.pairs[("A", "C")]) == 5
    # max_distance leaves far images unassigned: C's images lie ~3 arcsec from its centre
    with pytest.raises(ValueError, match=r"C \(0\) have fewer than 3 knots"):
        pairs_from_knots(cat, centres_sky(centres), max_distance=0.5 * u.arcsec)


def test_fluxes_are_copied():
    rows, centres, _ = synthetic(n_knots=5)
    cat = catalogue(rows)
    cat["flux_F150W"] = np.arange(len(cat), dtype=float) + 1
    cat["flux_err_F150W"] = 0.1 * np.ones(len(cat))
    kp = pairs_from_knots(cat, centres_sky(centres), bands=["F150W"])
    tab = kp.pairs[("A", "B")]
    ids = list(cat["id"])
    assert [cat["flux_F150W"][ids.index(i)] for i in tab["id1"]] == list(tab["flux1_F150W"])
    assert tab.meta["bands"] == ["F150W"]
    with pytest.raises(ValueError, match="no flux column 'flux_F200W'"):
        pairs_from_knots(cat, centres_sky(centres), bands=["F200W"])


@pytest.mark.parametrize("change, match", [
    (lambda cat, c: (cat, c, {"mapping": {"999.1": "A"}}), r"unknown image id\(s\) \['999.1'\]"),
    (lambda cat, c: (cat, c, {"mapping": {"100.1": "Z"}}), r"unknown macro-image\(s\) \['Z'\]"),
    (lambda cat, c: (cat[:5], c, {}), "fewer than 3 knots"),
    (lambda cat, c: (QTable({"id": list(cat["id"]) + ["900.1"],
                             "sky": SkyCoord([*cat["sky"], cat["sky"][0]])}), c, {}),
     "duplicate images"),
    (lambda cat, c: (QTable({"id": list(cat["id"]) + ["100.1"],
                             "sky": SkyCoord([*cat["sky"], cat["sky"][3]])}), c, {}),
     r"id\(s\) \['100.1'\] appear more than once"),
    (lambda cat, c: (cat, c, {"knots": ["100", "777"]}), r"system\(s\) \['777'\]"),
    (lambda cat, c: (cat, {"A": c["A"]}, {}), "at least 2 macro-images"),
    (lambda cat, c: (cat, c, {"assign": "model", "model": object()}), "no redshift"),
    (lambda cat, c: (cat, c, {"assign": "nearest"}), "assign must be"),
    (lambda cat, c: (cat, ["A", "B"], {}), "give their centres"),
])
def test_bad_input(change, match):
    rows, centres, _ = synthetic(n_knots=6)
    cat, c, kwargs = change(catalogue(rows), centres_sky(centres))
    with pytest.raises((ValueError, TypeError), match=match):
        pairs_from_knots(cat, c, **kwargs)


# ---------------------------------------------------------------- model assignment

PAR = """runmode
    reference 3 150.0 2.0
    end
potential O1
    profile       81
    x_centre      0.0
    y_centre      0.0
    ellipticity   0.3
    angle_pos     20.0
    core_radius   3.0
    cut_radius    500.0
    v_disp        1100.0
    z_lens        0.4
    end
potential G1
    profile       81
    x_centre      {gx}
    y_centre      {gy}
    ellipticity   0.0
    angle_pos     0.0
    core_radius   0.01
    cut_radius    3.0
    v_disp        120.0
    z_lens        0.4
    end
""" + COSMOLOGY + "fini\n"


@pytest.fixture(scope="module")
def knotty_lens(tmp_path_factory):
    """A Lenstool model whose source at BETA0 has 3+ images, one of them near a member."""
    from lensdual.parametric import read_lenstool

    path = tmp_path_factory.mktemp("knots") / "model.par"
    path.write_text(PAR.format(gx=100.0, gy=100.0))
    model = read_lenstool(path)
    system = model.lens_system(2.0)
    beta0 = np.array([[1.5, 1.0]])
    macro = system.solve_images(beta0 * u.arcsec, half_width=80 * u.arcsec)
    xy = np.column_stack([macro["x"].to_value(u.arcsec), macro["y"].to_value(u.arcsec)])
    assert len(xy) >= 3
    return path, model, system, beta0, xy


def _knot_images(system, beta0):
    """The images of 12 knots around ``beta0``: positions (arcsec) and catalogue ids
    whose sub-indices do not follow the macro-images."""
    rng = np.random.default_rng(3)
    knots = beta0 + rng.uniform(-0.15, 0.15, (12, 2))
    images = system.solve_images(knots * u.arcsec, half_width=80 * u.arcsec)
    xy = np.column_stack([images["x"].to_value(u.arcsec), images["y"].to_value(u.arcsec)])
    sub = {}
    ids = []
    for s in images["source"]:
        sub[s] = sub.get(s, 0) + 1
        ids.append(f"{200 + s}.{sub[s]}")
    return xy, np.array(ids)


def test_model_assignment_matches_the_truth(knotty_lens):
    from lensdual.parametric import read_lenstool

    _, model, system, beta0, macro_xy = knotty_lens
    xy, ids = _knot_images(system, beta0)
    truth = np.argmin(np.hypot(*(xy[:, None, :] - macro_xy[None]).transpose(2, 0, 1)), axis=1)
    # plus an extra "image" near macro-image 0 that the model maps to no macro-image
    fake = macro_xy[0] + [0.9, -0.7]
    ids = np.append(ids, "299.1")
    xy = np.vstack([xy, fake, macro_xy[1] + [0.8, 0.8]])
    ids = np.append(ids, "299.2")
    sky = model.to_sky(xy * u.arcsec)
    cat = QTable({"id": ids, "sky": sky, "z": np.full(len(ids), 2.0)})
    names = [f"M{k}" for k in range(len(macro_xy))]
    centres = dict(zip(names, model.to_sky(macro_xy * u.arcsec), strict=True))
    kp = pairs_from_knots(cat, centres, model=model)
    assert kp.assign == "model" and kp.z_source == 2.0
    got = dict(zip(kp.images["id"], kp.images["macro"], strict=True))
    for i, t in zip(ids[:len(truth)], truth, strict=True):
        assert got[i] == names[t], i
    st = dict(zip(kp.images["id"], kp.images["status"], strict=True))
    assert st["299.1"] != "used" and st["299.2"] != "used"
    # the model-based comparison: mu_model is the model's own |mu1/mu2| at the knots
    from lensdual.parametric import compare_size_with_models

    tab = kp.pairs[(names[0], names[1])]
    out = compare_size_with_models(tab, model, sigma_pos=0.01 * u.arcsec)
    t1 = model.to_model_frame(tab["sky1"])
    t2 = model.to_model_frame(tab["sky2"])
    ratio = np.abs(system.magnification(t1) / system.magnification(t2))
    name = out.meta["models"][0]
    np.testing.assert_allclose(out[f"mu_{name}"], ratio, rtol=1e-9)
    # exact positions: mu_size agrees with the model within the quoted errors
    good = np.isin(out["mu_size_status"], ["ok", "misfit"])
    assert good.sum() >= len(out) // 2
    assert np.all(out[f"snr_{name}"][good] < 4)
    # the position part of the model error grows with sigma_pos
    out2 = compare_size_with_models(tab, {"lt": model, "again": read_lenstool(knotty_lens[0])},
                                    sigma_pos=0.05 * u.arcsec)
    assert np.all(out2["ln_mu_lt_err"] > out[f"ln_mu_{name}_err"])
    np.testing.assert_allclose(out2["mu_lt"], out2["mu_again"])
    # the sign of det J is determined where 1 / sigma(ln mu_size) reaches the threshold
    np.testing.assert_allclose(out["parity_snr"][good], 1 / out["ln_mu_size_err"][good])
    determined = good & (out["parity_snr"] >= 3)
    assert determined.sum() >= 2
    np.testing.assert_array_equal(out["parity"] != 0, determined)
    np.testing.assert_array_equal(out["parity"][determined], out[f"parity_{name}"][determined])


def test_a_determined_parity_flip_is_a_disagreement(knotty_lens, monkeypatch):
    """A model whose magnification ratio has the other sign: every pair whose
    parity is determined disagrees, whatever its SNR; the undetermined ones do not."""
    from lensdual.parametric import compare_size_with_models
    from lensdual.parametric import knots as knots_module

    _, model, system, beta0, macro_xy = knotty_lens
    xy, ids = _knot_images(system, beta0)
    cat = QTable({"id": ids, "sky": model.to_sky(xy * u.arcsec), "z": np.full(len(ids), 2.0)})
    names = [f"M{k}" for k in range(len(macro_xy))]
    centres = dict(zip(names, model.to_sky(macro_xy * u.arcsec), strict=True))
    tab = pairs_from_knots(cat, centres, model=model).pairs[(names[0], names[1])]
    real = knots_module._model_ratio

    def flipped(*args):
        mu1, mu2, ratio, ln_model = real(*args)
        return mu1, -mu2, ratio, ln_model

    same = compare_size_with_models(tab, model, sigma_pos=0.01 * u.arcsec)
    monkeypatch.setattr(knots_module, "_model_ratio", flipped)
    out = compare_size_with_models(tab, model, sigma_pos=0.01 * u.arcsec)
    name = out.meta["models"][0]
    np.testing.assert_array_equal(out[f"snr_{name}"], same[f"snr_{name}"])
    determined = out["parity"] != 0
    assert determined.any() and not same[f"disagree_{name}"][determined].any()
    assert out[f"disagree_{name}"][determined].all()
    np.testing.assert_array_equal(out[f"disagree_{name}"][~determined],
                                  same[f"disagree_{name}"][~determined])


# ---------------------------------------------------------------- sigma from residuals


@pytest.mark.parametrize("sigma", [0.002, 0.02])
def test_estimate_sigma_pos_is_unbiased_on_polynomial_maps(sigma):
    rng = np.random.default_rng(11)
    est = []
    for _ in range(60):
        t2 = rng.uniform(-2, 2, (25, 2))
        t1 = (t2 @ np.array([[1.4, 0.4], [0.2, -0.7]]).T
              + 0.04 * np.column_stack([t2[:, 0] ** 2, t2[:, 0] * t2[:, 1]]))
        n1, n2 = sigma * rng.standard_normal((2, 25, 2))
        est.append(estimate_sigma_pos((t1 + n1) * u.arcsec, (t2 + n2) * u.arcsec)
                   .to_value(u.arcsec))
    # sigma^2 is unbiased; sigma (its square root) is biased low by ~ 1/(4 dof)
    assert np.mean(np.square(est)) == pytest.approx(sigma**2, rel=0.08)
    assert np.std(est) / sigma < 0.2


def test_estimate_sigma_pos_bad_input():
    t = np.zeros((5, 2)) * u.arcsec
    with pytest.raises(ValueError, match="at least 6 pairs"):
        estimate_sigma_pos(t, t)
    with pytest.raises(ValueError, match="differ in length"):
        estimate_sigma_pos(np.zeros((7, 2)) * u.arcsec, np.zeros((8, 2)) * u.arcsec)
    with pytest.raises(TypeError):
        estimate_sigma_pos(np.zeros((7, 2)), np.zeros((7, 2)))


def test_read_macro_images(tmp_path):
    path = tmp_path / "knots.mul"
    path.write_text("#1.1 177.39700 22.396007 0.2 0.2 0.0 1.4888 0.0\n"
                    "#1.2 177.39941 22.397438\n# a comment\n"
                    "1002.1 177.40343 22.402419 0.2 0.2 0.0 1.4888 25\n")
    c = read_macro_images(path, ["1.1", "1.2"])
    assert list(c) == ["1.1", "1.2"]
    assert c["1.2"].dec.deg == pytest.approx(22.397438)
    with pytest.raises(ValueError, match=r"no commented line for the macro-image\(s\) \['1.3'\]"):
        read_macro_images(path, ["1.1", "1.3"])


def test_a_byte_order_mark_is_not_part_of_the_first_line(tmp_path):
    """A Lenstool catalogue saved with a UTF-8 byte-order mark (as some Windows editors
    write it) reads as the same file without one, whatever its first line holds: a
    commented macro-image centre (read_macro_images, pairs_from_knots) or the
    #REFERENCE header of relative positions (read_lenstool_images)."""
    from lensdual.parametric import read_lenstool_images

    rows, centres, _ = synthetic(n_knots=9, seed=4)
    names = {"1.1": centres["A"], "1.2": centres["B"], "1.3": centres["C"]}
    plain = write_mul(tmp_path / "plain.mul", rows, names)
    rel = tmp_path / "rel.mul"
    rel.write_text("#REFERENCE 3 150.0 2.0\n" + "".join(
        f"{i} {-x:.6f} {y:.6f} 0.2 0.2 0.0 1.5 25\n" for i, (x, y) in rows.items()))
    for path in (plain, rel):
        bom = path.with_name("bom_" + path.name)
        bom.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
        a = read_lenstool_images(path, reference=REF)
        b = read_lenstool_images(bom, reference=REF)
        assert list(b["id"]) == list(a["id"]) == list(rows)
        assert np.all(b["sky"].separation(a["sky"]) < 1e-6 * u.arcsec)
    bom = tmp_path / "bom_plain.mul"
    centres_a, centres_b = (read_macro_images(p, list(names)) for p in (plain, bom))
    assert list(centres_b) == list(names)
    for name in names:
        assert centres_b[name].separation(centres_a[name]) < 1e-6 * u.arcsec
    kp_a = pairs_from_knots(plain, centres_a)
    kp_b = pairs_from_knots(bom, centres_b)
    assert list(kp_b.pairs) == list(kp_a.pairs) == [("1.1", "1.2"), ("1.1", "1.3"),
                                                    ("1.2", "1.3")]
    for key, tab in kp_a.pairs.items():
        assert list(kp_b.pairs[key]["knot"]) == list(tab["knot"])
        np.testing.assert_array_equal(kp_b.pairs[key]["x2"], tab["x2"])


# ---------------------------------------------------------------- real data

MACS1149 = HFF / "macs1149_v4"


@pytest.mark.skipif(not MACS1149.is_dir(), reason="needs ../shared/data/hff_cats_lenstool")
def test_macs1149_knots_by_centre_and_by_model():
    from lensdual.parametric import read_lenstool

    cat = MACS1149 / "imawcs_spiral_secured.mul"
    centres = read_macro_images(cat, ["1.1", "1.2", "1.3"])
    knots = lambda s: 1000 <= int(s) < 2000  # noqa: E731
    by_centre = pairs_from_knots(cat, centres, knots=knots)
    model = read_lenstool(MACS1149 / "best.par")
    by_model = pairs_from_knots(cat, centres, knots=knots, model=model)
    assert set(by_model.pairs) == {("1.1", "1.2"), ("1.1", "1.3"), ("1.2", "1.3")}
    for kp in (by_centre, by_model):
        status = dict(zip(kp.images["id"], kp.images["status"], strict=True))
        # SN Refsdal's Einstein cross (1999.x) and the images around the cluster
        # member that lenses it are never used
        assert all(status[f"1999.{k}"] != "used" for k in range(1, 5))
        assert all(status[f"1050.{k}"] != "used" for k in range(3, 6))
        assert len(kp.pairs[("1.1", "1.3")]) >= 15
    # the model assigns at least as many knots as the centres
    for key in by_model.pairs:
        assert len(by_model.pairs[key]) >= len(by_centre.pairs[key])


# ---------------------------------------------------------------- catalogue-only run


def write_mul(path, rows, centres, z=1.5):
    """A Lenstool catalogue (absolute RA Dec) of ``rows``, macro centres commented."""
    lines = []
    for name, c in centres.items():
        s = tangent_to_sky(c[0], c[1], REF)
        lines.append(f"#{name} {s.ra.deg:.8f} {s.dec.deg:.8f} 0.2 0.2 0.0 {z} 0.0")
    for ident, xy in rows.items():
        s = tangent_to_sky(xy[0], xy[1], REF)
        lines.append(f"{ident} {s.ra.deg:.8f} {s.dec.deg:.8f} 0.2 0.2 0.0 {z} 25")
    path.write_text("\n".join(lines) + "\n")
    return path


def knot_config(tmp_path, **knots):
    rows, centres, _ = synthetic(n_knots=9, seed=4)
    rng = np.random.default_rng(5)
    rows = {k: v + 0.01 * rng.standard_normal(2) for k, v in rows.items()}
    write_mul(tmp_path / "knots.mul", rows, {"1.1": centres["A"], "1.2": centres["B"],
                                             "1.3": centres["C"]})
    table = {"catalogue": "knots.mul", "macro_images": ["1.1", "1.2", "1.3"]}
    table.update(knots)
    from lensdual.config import format_config

    path = tmp_path / "run.toml"
    path.write_text(format_config({"knots": table}))
    return path


def test_catalogue_only_run(tmp_path, capsys):
    from lensdual.cli import main
    from lensdual.config import load_config

    path = knot_config(tmp_path, systems=[100, 200])
    cfg = load_config(path)
    assert cfg.knots.assign == "centre" and cfg.knots.systems == ("range", 100, 200)
    assert cfg.bands == {} and cfg.knots.sigma_pos == "auto"
    out = tmp_path / "out"
    assert main(["run", str(path), "--outdir", str(out), "--quiet"]) == 0
    names = sorted(p.name for p in out.iterdir() if not p.name.startswith("."))
    assert names == ["knot_images.ecsv", "knots_1.1_1.2.ecsv", "knots_1.1_1.3.ecsv",
                     "knots_1.2_1.3.ecsv", "report.txt"]
    tab = QTable.read(out / "knots_1.1_1.3.ecsv")
    a, c = MAPS["A"][1], MAPS["C"][1]
    truth = abs(np.linalg.det(a) / np.linalg.det(c))
    ok = tab["mu_size_status"] == "ok"
    assert ok.sum() >= 7
    pulls = np.log(tab["mu_size"][ok] / truth) / tab["ln_mu_size_err"][ok]
    assert np.all(np.abs(pulls) < 4)
    report = (out / "report.txt").read_text()
    assert "Macro-images 1.1 (L1) / 1.3 (L2): 9 knots" in report
    assert "measured from the residuals" in report


@pytest.mark.parametrize("knots, match", [
    ({"assign": "model"}, r"\[knots\] models: assign = \"model\" needs"),
    ({"assign": "mapping"}, r"\[knots\] mapping: required"),
    ({"systems": [5, 2]}, r"lo < hi"),
    ({"macro_images": ["1.1"]}, r"at least 2 names"),
    ({"models": ["absent.par"]}, r"file not found"),
    ({"sigma_pos": "fast"}, r"\[knots\] sigma_pos"),
    ({"centres": {"1.1": "10 20"}}, r"a centre for every macro-image"),
    ({"colour": 1}, r"unknown key"),
])
def test_catalogue_only_config_errors(tmp_path, knots, match):
    from lensdual.config import ConfigError, load_config

    with pytest.raises(ConfigError, match=match):
        load_config(knot_config(tmp_path, **knots))


def test_knots_with_images_is_refused(tmp_path):
    from lensdual.config import ConfigError, load_config

    path = knot_config(tmp_path)
    path.write_text(path.read_text() + '[bands.F150W]\npsf_fwhm = "0.07 arcsec"\n')
    with pytest.raises(ConfigError, match=r"catalogue-only; remove \[bands\]"):
        load_config(path)


@pytest.mark.skipif(not MACS1149.is_dir(), reason="needs ../shared/data/hff_cats_lenstool")
def test_macs1149_catalogue_only_run(tmp_path):
    from lensdual.cli import main

    path = tmp_path / "run.toml"
    path.write_text(f"""[knots]
catalogue = "{MACS1149 / 'imawcs_spiral_secured.mul'}"
macro_images = ["1.1", "1.2", "1.3"]
systems = [1000, 2000]
models = ["{MACS1149 / 'best.par'}"]
""")
    out = tmp_path / "out"
    assert main(["run", str(path), "--outdir", str(out), "--quiet"]) == 0
    tab = QTable.read(out / "knots_1.1_1.3.ecsv")
    assert len(tab) >= 15
    # the parity of the model and of the constellation agree wherever it is determined
    determined = tab["parity"] != 0
    assert determined.sum() >= 12
    assert np.all(tab["parity"][determined] == tab["parity_macs1149_v4"][determined])
    np.testing.assert_array_equal(determined, tab["parity_snr"] >= 3)
    # knot 1052 of 1.1 / 1.2 has the model's opposite sign at 0.8 sigma: undetermined,
    # neither an agreement nor a disagreement
    t12 = QTable.read(out / "knots_1.1_1.2.ecsv")
    k = list(t12["knot"]).index("1052")
    assert t12["parity"][k] == 0 and t12["parity_snr"][k] < 1
    assert not t12["disagree_macs1149_v4"][k]
    report = (out / "report.txt").read_text()
    assert "where it is determined (undetermined: " in report and "1052" in report
    # most knots agree with the model within the combined errors
    assert np.mean(tab["snr_macs1149_v4"] < 3) > 0.8
    assert (out / "knots_1.1_1.3.png").stat().st_size > 10000


def test_plot_size_vs_model_takes_unbounded_errors():
    """A pair whose error of ln mu is beyond exp's range (an untestable fit
    with |det J| near 0) gets an unbounded bar, without an overflow warning
    (the suite turns warnings into errors), and every point is drawn."""
    import matplotlib

    matplotlib.use("Agg")
    from astropy.table import Table

    from lensdual.parametric import plot_size_vs_model

    t = Table()
    t["pair_id"] = [0, 1, 2]
    t["mu_size"] = [1.0, 1.2, 0.8]
    t["ln_mu_size_err"] = [0.05, 0.1, 800.0]
    t["mu_size_status"] = ["ok", "misfit", "untestable"]
    t["mu_cats"] = [1.05, 1.1, 0.9]
    t["ln_mu_cats_err"] = [0.02, 0.02, 0.02]
    t["disagree_cats"] = [False, False, False]
    t.meta["models"] = ["cats"]
    ax = plot_size_vs_model(t)
    drawn = sum(len(c.get_children()[0].get_xdata()) for c in ax.containers)
    assert drawn == 3
    labels = [x.get_text() for x in ax.texts]
    assert labels == ["0", "1", "2"]

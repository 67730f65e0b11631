"""``lensdual infer``: its configuration, the posterior of mock constellations, the outputs."""

import json
import os
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest
from astropy import units as u
from astropy.table import QTable

pytest.importorskip("pyHalo")

from lensdual import check_duality  # noqa: E402
from lensdual.cli import main  # noqa: E402
from lensdual.config import ConfigError, load_inference_config  # noqa: E402
from lensdual.inference import (  # noqa: E402
    SubhaloPopulation,
    abundance_posterior,
    apply_population,
    half_mode_posterior,
    simulate_anomalies,
)
from lensdual.simulation import noisy_constellation  # noqa: E402
from lensdual.simulation.families import calibration_system, clean_constellation  # noqa: E402

DOCS = Path(__file__).resolve().parents[1] / "docs"
FAMILY = "smacs_analog"
#: A small forward model: 6 abundances, 100 realisations; no calibration (its own tests).
SMALL = {"sigma_sub": [0.002, 0.2], "n_sigma_sub": 6, "n_realisations": 100,
         "calibrate": False}
OUTPUTS = ("posterior.ecsv", "posterior.png", "report.txt")


def _mock(path, seed, truth=0.05, n_sources=12, test="auto"):
    """A check_duality result of one mock universe of the family, written as ECSV."""
    system, info = calibration_system(FAMILY)
    pairs = clean_constellation(FAMILY, n_sources, seed=seed)
    pop = SubhaloPopulation(info["z_lens"], info["z_source"])
    mock = apply_population(pairs, system, pop, truth / u.kpc**2, seed=seed + 100)
    noisy = noisy_constellation(mock, sigma_pos=5 * u.mas, flux_rel_err=0.02, seed=seed + 200)
    result = check_duality(noisy, sigma_pos=5 * u.mas, seed=0, test=test)
    result.write(path, format="ascii.ecsv", overwrite=True)
    return path


@pytest.fixture(scope="module")
def mocks(tmp_path_factory):
    """Two mock constellations' duality results (ECSV) in one folder."""
    folder = tmp_path_factory.mktemp("infer_mocks")
    return [_mock(folder / "mock_a.ecsv", 3), _mock(folder / "mock_b.ecsv", 4)]


def _value(v):
    return json.dumps(v)  # strings, numbers and lists of them are TOML too


def write_config(path, inference, systems, output=None):
    """A lensdual infer file: [output], [inference] and one [[inference.system]] each."""
    lines = []
    if output is not None:
        lines += ["[output]"] + [f"{k} = {_value(v)}" for k, v in output.items()] + [""]
    lines += ["[inference]"] + [f"{k} = {_value(v)}" for k, v in inference.items()]
    for system in systems:
        lines += ["", "[[inference.system]]"] + [f"{k} = {_value(v)}" for k, v in system.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


def _system(path, **extra):
    return {"pairs": str(path), "family": FAMILY, **extra}


def _problems(path, outdir=None):
    with pytest.raises(ConfigError) as info:
        load_inference_config(path, outdir=outdir)
    return info.value.problems


# ---------------------------------------------------------------- end to end


def _infer(cfg, out, capsys):
    """``lensdual infer cfg --outdir out``: it succeeds and writes every output;
    its printed text and the posterior table."""
    assert main(["infer", str(cfg), "--outdir", str(out)]) == 0
    text = capsys.readouterr().out
    for name in OUTPUTS:
        assert (out / name).is_file(), name
    return text, QTable.read(out / "posterior.ecsv", format="ascii.ecsv")


def test_infer_end_to_end(mocks, tmp_path, capsys):
    """One mock with its composite weight: the outputs, the report, the posterior's meta."""
    cfg = write_config(tmp_path / "one.toml", {**SMALL, "n_mocks": 20, "seed": 1},
                       [_system(mocks[0], name="mock A")])
    out = tmp_path / "out"
    text, post = _infer(cfg, out, capsys)
    m = post.meta["inference"]
    assert len(post) == 6 and m["n_systems"] == 1
    assert m["interval_95"][0] < m["median"] < m["interval_95"][1]
    (system,) = post.meta["systems"]
    assert system["name"] == "mock A" and system["weight_source"] == "composite"
    assert 0 < system["weight"] <= 1
    assert system["n_tested"] == m["n_pairs"]
    assert system["paper_bound"].unit == u.kpc**-2
    # the report names the interval and the paper's bound side by side
    report = (out / "report.txt").read_text()
    assert report.strip() in text
    assert f"{m['median'].to_value(u.kpc**-2):.3g}" in report
    assert "binomial bound" in report
    assert f"{system['paper_bound'].to_value(u.kpc**-2):.3g}" in report
    assert not [p for p in tmp_path.iterdir() if ".partial-" in p.name]


def test_two_systems_are_the_api_s_posterior(mocks, tmp_path):
    """Weight 1, two systems: the posterior is abundance_posterior of the two forward
    models (the seeds of lensdual infer: one stream per system from [inference] seed)."""
    from lensdual._inference_run import format_inference_report, run_inference

    cfg = write_config(tmp_path / "two.toml", {**SMALL, "weight": 1, "seed": 7},
                       [_system(p) for p in mocks])
    config = load_inference_config(cfg)
    assert [s.name for s in config.systems] == ["mock_a", "mock_b"]
    run = run_inference(config)
    system, info = calibration_system(FAMILY)
    pop = SubhaloPopulation(info["z_lens"], info["z_source"])
    seeds = np.random.SeedSequence(7).generate_state(4)
    tables = [QTable.read(p, format="ascii.ecsv") for p in mocks]
    sims = [simulate_anomalies(t, system, pop, config.grid, n_realisations=100,
                               seed=int(seeds[2 * i])) for i, t in enumerate(tables)]
    for mine, theirs in zip(run.simulations, sims, strict=True):
        np.testing.assert_array_equal(mine.delta, theirs.delta)
    expected = abundance_posterior(tables, sims)
    np.testing.assert_allclose(run.posterior["log_likelihood"], expected["log_likelihood"])
    assert run.posterior.meta["inference"]["n_systems"] == 2
    assert [s["weight"] for s in run.posterior.meta["systems"]] == [1.0, 1.0]
    # the default, anomaly = "auto", with tables of the geometric test (12 sources: the
    # pipeline's "auto" test runs the geometric one)
    assert run.posterior.meta["inference"]["anomaly"] == "geometric"
    assert run.posterior.meta["inference"]["anomaly_source"] == "auto"
    report = format_inference_report(run.posterior)
    assert 'anomalies: geometric (the flux ratio against mu_size); anomaly = "auto"' in report
    # the same mocks analysed by the joint test: "auto" reads the joint anomalies, as
    # anomaly = "joint" does
    joint_paths = [_mock(tmp_path / f"joint_{k}.ecsv", seed, test="joint")
                   for k, seed in enumerate((3, 4))]
    joint_tables = [QTable.read(p, format="ascii.ecsv") for p in joint_paths]
    expected = abundance_posterior(joint_tables, sims, anomaly="joint")
    for extra in ({"anomaly": "joint"}, {}):
        cfg = write_config(tmp_path / "joint.toml", {**SMALL, "weight": 1, "seed": 7, **extra},
                           [_system(p) for p in joint_paths])
        joint = run_inference(load_inference_config(cfg))
        np.testing.assert_allclose(joint.posterior["log_likelihood"],
                                   expected["log_likelihood"])
        m = joint.posterior.meta["inference"]
        assert m["anomaly"] == "joint"
        assert m["anomaly_source"] == ("configured" if extra else "auto")
    # one table of each: "auto" falls back on the geometric anomalies, "joint" is refused
    mixed = [_system(joint_paths[0]), _system(mocks[1])]
    config = load_inference_config(write_config(tmp_path / "mixed.toml",
                                                {**SMALL, "weight": 1}, mixed))
    assert config.anomaly == "geometric" and config.anomaly_source == "auto"
    problems = _problems(write_config(tmp_path / "mixed_joint.toml",
                                      {**SMALL, "weight": 1, "anomaly": "joint"}, mixed))
    assert problems == ['[inference] anomaly: "joint" reads the joint test\'s prediction, and '
                        "the tables of mock_b are of the geometric test (check_duality "
                        'test="joint", or lensdual run with 13 sources or more); use '
                        '"geometric" or "auto"']


def test_line_of_sight_haloes_reach_the_forward_model(mocks, tmp_path):
    """[inference] los_normalization and two_halo build the population the API builds,
    and the posterior's metadata names it."""
    from lensdual._inference_run import run_inference

    cfg = write_config(tmp_path / "los.toml", {**SMALL, "weight": 1, "seed": 7,
                                               "los_normalization": 0.5, "two_halo": False},
                       [_system(mocks[0])])
    config = load_inference_config(cfg)
    assert config.los_normalization == 0.5 and config.two_halo is False
    run = run_inference(config)
    system, info = calibration_system(FAMILY)
    pop = SubhaloPopulation(info["z_lens"], info["z_source"], los_normalization=0.5,
                            two_halo=False)
    seed = int(np.random.SeedSequence(7).generate_state(2)[0])
    table = QTable.read(mocks[0], format="ascii.ecsv")
    sim = simulate_anomalies(table, system, pop, config.grid, n_realisations=100, seed=seed)
    np.testing.assert_array_equal(run.simulations[0].delta, sim.delta)
    assert "los_normalization=0.5" in run.posterior.meta["inference"]["population"]


def test_two_systems_on_dask_are_serial(mocks, tmp_path):
    """The forward models of two systems on a 2-worker LocalCluster: identical to serial."""
    distributed = pytest.importorskip("distributed")
    from lensdual._inference_run import run_inference

    cfg = write_config(tmp_path / "dask.toml", {**SMALL, "weight": 0.5, "seed": 2},
                       [_system(p) for p in mocks])
    config = load_inference_config(cfg)
    serial = run_inference(config)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        on_dask = run_inference(config, client=client)
    for a, b in zip(serial.simulations, on_dask.simulations, strict=True):
        np.testing.assert_array_equal(a.delta, b.delta)
    np.testing.assert_array_equal(serial.posterior["log_likelihood"],
                                  on_dask.posterior["log_likelihood"])


def test_threads_give_the_serial_result(mocks, tmp_path):
    cfg = write_config(tmp_path / "threads.toml", {**SMALL, "weight": 1},
                       [_system(mocks[0])])
    one, two = tmp_path / "one", tmp_path / "two"
    assert main(["infer", str(cfg), "--outdir", str(one), "--quiet"]) == 0
    assert main(["infer", str(cfg), "--outdir", str(two), "--quiet", "--threads", "2"]) == 0
    a = QTable.read(one / "posterior.ecsv", format="ascii.ecsv")
    b = QTable.read(two / "posterior.ecsv", format="ascii.ecsv")
    np.testing.assert_array_equal(a["log_likelihood"], b["log_likelihood"])


# ---------------------------------------------------------------- the calibration


def test_calibrated_posterior_is_the_api_s(mocks, tmp_path, capsys):
    """The default calibration, two systems: the posterior is abundance_posterior
    recalibrated on calibrate_posterior's mocks of each system's clean constellation
    (the seeds of lensdual infer), and the report says so."""
    from lensdual._inference_run import clean_pairs, run_inference
    from lensdual.inference import calibrate_posterior

    inference = {k: v for k, v in SMALL.items() if k != "calibrate"}
    cfg = write_config(tmp_path / "cal.toml", {**inference, "n_calibration": 80, "seed": 7},
                       [_system(p) for p in mocks])
    config = load_inference_config(cfg)
    assert config.calibrate and config.effective_weight == 1.0 and config.n_calibration == 80
    run = run_inference(config)
    system, info = calibration_system(FAMILY)
    pop = SubhaloPopulation(info["z_lens"], info["z_source"])
    seeds = np.random.SeedSequence([7, 1]).generate_state(2)
    tables = [QTable.read(p, format="ascii.ecsv") for p in mocks]
    calibrations = []
    for tab, sim, seed in zip(tables, run.simulations, seeds, strict=True):
        duality = tab.meta["duality"]
        calibrations.append(calibrate_posterior(
            clean_pairs(tab, system, pop, 0.02), system, sim, sigma_pos=5 * u.mas,
            flux_rel_err=0.02, n_mocks=80, seed=int(seed), method=duality["method"],
            snr_definition=duality["snr_definition"],
            snr_threshold=duality["snr_threshold"]))
    expected = abundance_posterior(tables, run.simulations, calibrations=calibrations)
    np.testing.assert_allclose(run.posterior["cdf"], expected["cdf"], atol=1e-12)
    m = run.posterior.meta["inference"]
    assert m["calibrated"] and m["n_mocks"] + m["n_mocks_left_out"] == 80
    assert all(s["calibrated"] and s["weight_source"] == "default"
               for s in run.posterior.meta["systems"])
    out = tmp_path / "out"
    text, post = _infer(cfg, out, capsys)
    np.testing.assert_allclose(post["cdf"], expected["cdf"], atol=1e-12)
    assert post.meta["inference"]["mock_coverage_uncalibrated"]["68"] == pytest.approx(
        m["mock_coverage_uncalibrated"]["68"])
    assert f"calibrated on {m['n_mocks']} mock universes" in " ".join(text.split())


def test_calibration_problems(mocks, tmp_path):
    ok = [_system(mocks[0])]
    cases = [
        ({**SMALL, "calibrate": "yes"},
         "[inference] calibrate: expected a boolean (true or false)"),
        ({**SMALL, "n_calibration": 20}, "[inference] n_calibration: must be >= 50, got 20"),
    ]
    for inference, expected in cases:
        problems = _problems(write_config(tmp_path / "bad.toml", inference, ok))
        assert len(problems) == 1 and problems[0].startswith(expected), problems
    # a grid of half-mode masses is calibrated by default too
    grid = {k: v for k, v in SMALL.items() if k != "calibrate"}
    config = load_inference_config(write_config(
        tmp_path / "hm.toml", {**grid, "model": "WDM", "log_mhm": [6, 8]}, ok))
    assert config.calibrate and config.effective_weight == 1.0


# ---------------------------------------------------------------- the half-mode mass


def test_half_mode_grid_end_to_end(mocks, tmp_path, capsys):
    """log_mhm a list with WDM: the joint posterior, its report (both marginals) and figure."""
    from lensdual._inference_run import run_inference

    inference = {**SMALL, "n_mocks": 20, "seed": 1, "model": "WDM", "log_mhm": [9, 6]}
    cfg = write_config(tmp_path / "hm.toml", inference, [_system(mocks[0], name="mock A")])
    config = load_inference_config(cfg)
    assert config.half_mode and config.log_mhm == (6.0, 9.0)
    out = tmp_path / "out"
    text, post = _infer(cfg, out, capsys)
    m = post.meta["inference"]
    assert "log10_mhm" in post.colnames and len(post) == 2 * 6
    assert sorted(set(post["log10_mhm"].tolist())) == [6.0, 9.0]
    assert 6 <= m["log10_mhm_median"] <= m["log10_mhm_upper_95"] <= 9
    (system,) = post.meta["systems"]
    assert system["weight_source"] == "composite" and 0 < system["weight"] <= 1
    assert 6 <= system["log10_mhm_upper_95"] <= 9
    report = (out / "report.txt").read_text()
    assert report.strip() in text
    assert "half-mode mass" in report and "95 % upper limit" in report
    assert f"{m['log10_mhm_upper_95']:.2f}" in report
    assert f"{m['median'].to_value(u.kpc**-2):.3g}" in report
    # the same seed for every mass: the lightest mass's forward model is a single-mass run's,
    # and the posterior is half_mode_posterior of the forward models
    run = run_inference(load_inference_config(
        write_config(tmp_path / "hm1.toml", {**inference, "weight": 1},
                     [_system(mocks[0], name="mock A")])))
    single = run_inference(load_inference_config(
        write_config(tmp_path / "one.toml", {**inference, "weight": 1, "log_mhm": 6},
                     [_system(mocks[0], name="mock A")])))
    assert [len(per_mass) for per_mass in run.simulations] == [1, 1]
    np.testing.assert_array_equal(run.simulations[0][0].delta, single.simulations[0].delta)
    tab = QTable.read(mocks[0], format="ascii.ecsv")
    expected = half_mode_posterior(tab, run.simulations, weights=1.0)
    np.testing.assert_allclose(run.posterior["log_likelihood"], expected["log_likelihood"])
    assert "log10_mhm" not in single.posterior.colnames


def test_calibrated_half_mode_posterior_is_the_api_s(mocks, tmp_path, capsys):
    """The default calibration with a grid of half-mode masses: both marginals are
    half_mode_posterior's recalibrated on calibrate_posterior's mocks, scored on every
    mass's forward model, and the report gives both mock coverages."""
    from lensdual._inference_run import clean_pairs, run_inference
    from lensdual.inference import calibrate_posterior

    inference = {k: v for k, v in SMALL.items() if k != "calibrate"}
    inference.update({"n_calibration": 60, "seed": 3, "model": "WDM", "log_mhm": [9, 6, 7]})
    cfg = write_config(tmp_path / "hmcal.toml", inference, [_system(mocks[0], name="mock A")])
    config = load_inference_config(cfg)
    run = run_inference(config)
    system, info = calibration_system(FAMILY)
    tab = QTable.read(mocks[0], format="ascii.ecsv")
    duality = tab.meta["duality"]
    pop = SubhaloPopulation(info["z_lens"], info["z_source"], model="WDM", log_mhm=6)
    (seed,) = np.random.SeedSequence([3, 1]).generate_state(1)
    sims = [per_mass[0] for per_mass in run.simulations]
    calibration = calibrate_posterior(
        clean_pairs(tab, system, pop, 0.02), system, sims, sigma_pos=5 * u.mas,
        flux_rel_err=0.02, n_mocks=60, seed=int(seed), method=duality["method"],
        snr_definition=duality["snr_definition"], snr_threshold=duality["snr_threshold"])
    expected = half_mode_posterior(tab, run.simulations, calibrations=calibration).meta[
        "inference"]
    m = run.posterior.meta["inference"]
    assert m["calibrated"] and m["n_mocks"] + m["n_mocks_left_out"] == 60
    for key in ("interval_68", "interval_95"):
        np.testing.assert_allclose(m[key].to_value(u.kpc**-2),
                                   expected[key].to_value(u.kpc**-2), rtol=1e-12)
    for key in ("log10_mhm_interval_68", "log10_mhm_interval_95", "marginal_log10_mhm"):
        np.testing.assert_allclose(m[key], expected[key], rtol=1e-12)
    assert m["weights"] == [1.0]
    text, post = _infer(cfg, tmp_path / "out", capsys)
    cov = m["log10_mhm_mock_coverage_uncalibrated"]
    assert (f"those of the half-mode mass {100 * cov['68']:.0f} %" in " ".join(text.split()))


def test_half_mode_grid_problems(mocks, tmp_path):
    ok = [_system(mocks[0])]
    wdm = {**SMALL, "model": "WDM"}
    cases = [
        ({**SMALL, "log_mhm": [6, 8]},
         '[inference] log_mhm: a list of half-mode masses (the joint posterior) needs '
         'model = "WDM"'),
        ({**wdm, "log_mhm": [7]},
         "[inference] log_mhm: a list needs at least two half-mode masses"),
        ({**wdm, "log_mhm": []},
         "[inference] log_mhm: a list needs at least two half-mode masses"),
        ({**wdm, "log_mhm": [6, 7, 6.0]},
         "[inference] log_mhm: each half-mode mass once, got 6 more than once"),
        ({**wdm, "log_mhm": [6, "7"]},
         "[inference] log_mhm: expected a number or a list of finite numbers (log10 Msun), "
         "got a list holding a string ('7')"),
        ({**wdm, "log_mhm": [6, 13]},
         "[inference] log_mhm: log_mhm must be <= 12"),
    ]
    for inference, expected in cases:
        problems = _problems(write_config(tmp_path / "bad.toml", inference, ok))
        assert len(problems) == 1 and problems[0].startswith(expected), (inference, problems)
    # a single number keeps its meaning
    config = load_inference_config(write_config(tmp_path / "one.toml", {**wdm, "log_mhm": 7},
                                                ok))
    assert config.log_mhm == 7.0 and not config.half_mode


# ---------------------------------------------------------------- the output directory


def test_rerun_replaces_only_its_own_outputs(mocks, tmp_path, capsys):
    cfg = write_config(tmp_path / "rerun.toml", {**SMALL, "weight": 1},
                       [_system(mocks[0])], output={"outdir": "results"})
    out = tmp_path / "results"  # [output] outdir is relative to the file
    assert main(["infer", str(cfg), "--quiet"]) == 0
    manifest = json.loads((out / ".lensdual-outputs").read_text())
    assert sorted(manifest["files"]) == sorted(OUTPUTS)
    (out / "notes.txt").write_text("mine")
    first = (out / "posterior.ecsv").read_bytes()
    assert main(["infer", str(cfg), "--quiet"]) == 0
    assert (out / "notes.txt").read_text() == "mine"  # never touched
    assert (out / "posterior.ecsv").read_bytes() == first  # the same seed, the same posterior
    assert sorted(json.loads((out / ".lensdual-outputs").read_text())["files"]) \
        == sorted(OUTPUTS)
    # an output the user changed is not lensdual's to replace any more
    (out / "report.txt").write_text("my edits")
    assert main(["infer", str(cfg), "--quiet"]) == 1
    assert "never replaces" in capsys.readouterr().err
    assert (out / "report.txt").read_text() == "my edits"
    assert (out / "posterior.ecsv").read_bytes() == first


def test_a_user_s_file_of_the_same_name_is_refused(mocks, tmp_path, capsys):
    cfg = write_config(tmp_path / "user.toml", {**SMALL, "weight": 1}, [_system(mocks[0])])
    out = tmp_path / "out"
    out.mkdir()
    (out / "posterior.png").write_bytes(b"not lensdual's")
    assert main(["infer", str(cfg), "--outdir", str(out), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "posterior.png" in err and "nothing was written" in err
    assert sorted(p.name for p in out.iterdir()) == ["posterior.png"]
    assert (out / "posterior.png").read_bytes() == b"not lensdual's"


def test_outdir_holding_an_input_is_refused(mocks, tmp_path):
    folder = tmp_path / "data"
    folder.mkdir()
    pairs = shutil.copy(mocks[0], folder / "pairs.ecsv")
    cfg = write_config(tmp_path / "inside.toml", SMALL, [_system(pairs)])
    problems = _problems(cfg, outdir=folder)
    assert problems == [f"outdir (argument): the output directory {folder.resolve()} holds "
                        "pairs.ecsv, read by this run; a run never replaces or removes its "
                        "own inputs, so choose an output directory that holds none of them"]


# ---------------------------------------------------------------- validation


def _bad(mocks, tmp_path):
    """(id, inference table, systems, expected problem) of configurations with one problem."""
    ok = _system(mocks[0])
    not_duality = tmp_path / "clean.ecsv"
    clean_constellation(FAMILY, 8, seed=1).write(not_duality, format="ascii.ecsv")
    return [
        ("unknown key", {**SMALL, "n_realisation": 100}, [ok],
         "[inference] n_realisation: unknown key (did you mean 'n_realisations'?)"),
        ("unknown system key", SMALL, [{**ok, "lens": "x"}],
         "[inference.system #1] lens: unknown key (did you mean 'lenstool'?)"),
        ("missing pairs file", SMALL, [_system(tmp_path / "nope.ecsv")],
         f"[inference.system #1] pairs: file not found: {tmp_path / 'nope.ecsv'}"),
        ("no pairs", SMALL, [{"family": FAMILY}],
         "[inference.system #1] pairs: required (the pairs.ecsv of lensdual run)"),
        ("inverted grid", {**SMALL, "sigma_sub": [0.3, 0.001]}, [ok],
         "[inference] sigma_sub: the bounds must be finite with 0 < min < max (a log-uniform "
         "prior), got [0.3, 0.001]"),
        ("grid of one bound", {**SMALL, "sigma_sub": [0.3]}, [ok],
         "[inference] sigma_sub: expected [min, max], two numbers in kpc^-2 (e.g. "
         "[0.001, 0.3]), got an array"),
        ("grid too short", {**SMALL, "n_sigma_sub": 1}, [ok],
         "[inference] n_sigma_sub: must be >= 2, got 1"),
        ("grid too short for the weight", {**SMALL, "n_sigma_sub": 3}, [ok],
         '[inference] n_sigma_sub: weight = "composite" needs at least 5 abundances (the '
         "slope and curvature of the log-likelihood), got 3"),
        ("few realisations", {**SMALL, "n_realisations": 10}, [ok],
         "[inference] n_realisations: must be >= 100, got 10"),
        ("weight above 1", {**SMALL, "weight": 1.5}, [ok],
         "[inference] weight: must be in (0, 1], got 1.5"),
        ("weight misspelt", {**SMALL, "weight": "compsite"}, [ok],
         "[inference] weight: expected \"composite\" or a number in (0, 1], got 'compsite' "
         "(did you mean 'composite'?)"),
        ("bad anomaly", {**SMALL, "anomaly": "field"}, [ok],
         "[inference] anomaly: 'field' is not one of 'auto', 'geometric', 'joint'"),
        ("bad model", {**SMALL, "model": "SIDM"}, [ok],
         "[inference] model: 'SIDM' is not one of 'CDM', 'WDM'"),
        ("WDM without log_mhm", {**SMALL, "model": "WDM"}, [ok],
         '[inference] log_mhm: required with model = "WDM" (log10 of the half-mode mass, '
         "Msun)"),
        ("negative line of sight", {**SMALL, "los_normalization": -1}, [ok],
         "[inference] los_normalization: must be >= 0 (0: no line-of-sight haloes, 1: "
         "pyHalo's default), got -1"),
        ("two_halo not a boolean", {**SMALL, "two_halo": 1}, [ok],
         "[inference] two_halo: expected a boolean (true or false), got"),
        ("host too heavy", {**SMALL, "log_m_host": 18.0}, [ok],
         "[inference] log_m_host: log_m_host must be <= 16.5, got 18.0"),
        ("unknown family", SMALL, [{**ok, "family": "smacs_analogue"}],
         "[inference.system #1] family: 'smacs_analogue' is not one of"),
        ("two lenses", SMALL, [{**ok, "lenstool": str(mocks[0])}],
         "[inference.system #1] family: give the smooth lens once"),
        ("no lens", SMALL, [{"pairs": str(mocks[0])}],
         "[inference.system #1] lenstool: missing: give the smooth lens"),
        ("z_source of a family", SMALL, [{**ok, "z_source": 2.0}],
         "[inference.system #1] z_source: a family has its own redshifts"),
        ("not a duality result", SMALL, [_system(not_duality)],
         f"[inference.system #1] pairs: {not_duality}: the constellation has no flux ratios "
         "tested for duality"),
        ("same names", SMALL, [ok, _system(mocks[0])],
         "[[inference.system]] name: the names ['mock_a'] are used twice"),
        ("no system", SMALL, [],
         "[[inference.system]]: missing: give at least one system"),
    ]


def test_bad_configurations_exit_2_and_write_nothing(mocks, tmp_path, capsys):
    for name, inference, systems, expected in _bad(mocks, tmp_path):
        cfg = write_config(tmp_path / "bad.toml", inference, systems)
        problems = _problems(cfg)
        assert len(problems) == 1 and problems[0].startswith(expected), (name, problems)
    out = tmp_path / "out"
    assert main(["infer", str(cfg), "--outdir", str(out)]) == 2
    assert "1 problem" in capsys.readouterr().err
    assert not out.exists()


def test_every_problem_at_once(mocks, tmp_path):
    cfg = tmp_path / "many.toml"
    cfg.write_text('[analysis]\nseed = 1\n\n[inference]\nweight = 2\nseed = -1\n\n'
                   '[[inference.system]]\npairs = "missing.ecsv"\n')
    problems = _problems(cfg)
    assert problems[0].startswith("[analysis]: unknown table")
    assert "[inference] seed: must be >= 0, got -1" in problems
    assert "[inference] weight: must be in (0, 1], got 2" in problems
    assert any(p.startswith("[inference.system #1] pairs: file not found") for p in problems)
    assert any(p.startswith("[inference.system #1] lenstool: missing") for p in problems)


def test_a_missing_inference_table(tmp_path):
    cfg = tmp_path / "empty.toml"
    cfg.write_text('[output]\noutdir = "x"\n')
    assert _problems(cfg) == ["[inference]: missing: a lensdual infer configuration needs an "
                              "[inference] table and at least one [[inference.system]]"]


def test_defaults_are_the_schema_s(mocks, tmp_path):
    from lensdual.config import INFERENCE_FIELDS

    cfg = write_config(tmp_path / "defaults.toml", {}, [_system(mocks[0])])
    config = load_inference_config(cfg)
    assert config.outdir == tmp_path.resolve() / "lensdual-inference"
    for f in INFERENCE_FIELDS:
        if f.table == "inference" and f.attribute != "anomaly":
            assert getattr(config, f.attribute) == f.default, f.name
    # "auto" is resolved on the tables (of the geometric test here)
    assert config.anomaly == "geometric" and config.anomaly_source == "auto"
    # the weight's default depends on the calibration: 1 with it (the default)
    assert config.calibrate and config.weight is None and config.effective_weight == 1.0
    assert config.grid.unit == u.kpc**-2 and len(config.grid) == 30


def test_documented_example_parses(tmp_path):
    """docs/_static/inference/infer.toml: every key is known and every value valid; its
    only problems, away from its data, are the files it names."""
    example = DOCS / "_static" / "inference" / "infer.toml"
    data = tomllib.loads(example.read_text())
    assert len(data["inference"]["system"]) == 2
    path = tmp_path / "infer.toml"
    shutil.copy(example, path)
    problems = _problems(path)
    assert problems and all("file not found" in p for p in problems), problems
    assert {p.split(":")[0] for p in problems} == {
        "[inference.system #1] pairs", "[inference.system #1] lenstool",
        "[inference.system #2] pairs"}
    # the documentation includes it
    assert "_static/inference/infer.toml" in (DOCS / "inference.rst").read_text()


def test_help_names_the_keys(capsys):
    assert main(["infer", "--help"]) == 0
    text = capsys.readouterr().out
    for key in ("--outdir", "--threads", "[inference]", "[[inference.system]]", "sigma_sub",
                "n_realisations", "weight", "lenstool", "family", "z_source", "posterior.ecsv"):
        assert key in text, key


# ---------------------------------------------------------------- a real Lenstool model


@pytest.mark.slow
def test_lenstool_system_in_the_model_s_frame(tmp_path):
    """A mock in the SMACS0723 Lenstool model, given as sky positions: lensdual infer
    places it in the model's frame (the family's positions back) and runs."""
    if not os.environ.get("LENSDUAL_SMACS0723_DIR"):
        pytest.skip("the SMACS0723 Lenstool model is not available")
    from astropy.coordinates import SkyCoord

    from lensdual._inference_run import _in_lens_frame
    from lensdual.parametric import read_lenstool

    par = Path(os.environ["LENSDUAL_SMACS0723_DIR"]) / "best.par"
    model = read_lenstool(par)
    system, info = calibration_system("smacs_lenstool")
    pairs = clean_constellation("smacs_lenstool", 10, seed=3)
    noisy = noisy_constellation(pairs, sigma_pos=5 * u.mas, flux_rel_err=0.02, seed=1)
    result = check_duality(noisy, sigma_pos=5 * u.mas, seed=0)
    for k in "12":
        xy = u.Quantity([result[f"x{k}"], result[f"y{k}"]]).T
        result[f"sky{k}"] = SkyCoord(model.to_sky(xy))
    result.write(tmp_path / "pairs.ecsv", format="ascii.ecsv")
    cfg = write_config(tmp_path / "lt.toml", {**SMALL, "weight": 1, "n_sigma_sub": 2,
                                               "sigma_sub": [0.001, 0.01]},
                       [{"pairs": "pairs.ecsv", "lenstool": str(par),
                         "z_source": info["z_source"]}])
    config = load_inference_config(cfg)
    tab, lens, z_lens, z_source, _, text = _in_lens_frame(config.systems[0])
    for k in "12":
        np.testing.assert_allclose(u.Quantity(tab[f"x{k}"]).to_value(u.arcsec),
                                   u.Quantity(result[f"x{k}"]).to_value(u.arcsec), atol=1e-6)
    assert (z_lens, z_source) == (info["z_lens"], info["z_source"])
    assert text == "Lenstool model best.par"
    out = tmp_path / "out"
    assert main(["infer", str(cfg), "--outdir", str(out), "--quiet"]) == 0
    post = QTable.read(out / "posterior.ecsv", format="ascii.ecsv")
    assert post.meta["systems"][0]["lens"] == "Lenstool model best.par"

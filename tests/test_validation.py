"""Tests of lensdual.simulation.validation and the validation figures."""

import matplotlib
import numpy as np
import pytest
from astropy import units as u

from lensdual.simulation.validation import (
    appendix_b_grid,
    estimator_errors,
    pair_placements,
    summarize_errors,
)

matplotlib.use("agg")


@pytest.fixture(scope="module")
def grid():
    return appendix_b_grid(n_sources=(10, 20), target_ratios=(-1.0, -0.5), seed=1)


def test_small_validation_grid(grid):
    assert set(np.asarray(grid["n_sources"])) == {10, 20}
    assert len(grid) == 2 * (10 + 20)
    # every panel's pairs have the targeted magnification ratio (within 20 %)
    for target in (-1.0, -0.5):
        sel = np.asarray(grid["target_ratio"]) == target
        assert np.median(grid["ratio"][sel]) == pytest.approx(target, rel=0.2)
    summary = summarize_errors(grid, by=())
    row = {r["method"]: r for r in summary}
    assert row["quad"]["half_width_68"] < 0.15  # Quad error scatter below 15 %
    assert row["quad2"]["median_abs_err"] < 0.5 * row["quad"]["median_abs_err"]
    assert row["quad2"]["abs_err_95"] <= row["quad"]["abs_err_95"]


def test_placements_reach_targets():
    from lensdual.simulation.validation import cusp_lens

    tab = pair_placements(cusp_lens(), [-1.0, -0.3])
    np.testing.assert_allclose(tab["ratio"], [-1.0, -0.3], atol=0.05)
    assert tab["reference"].shape == (2, 2, 2)


def test_estimator_errors_against_truth(grid):
    from lensdual.simulation import smacs0723_analog

    pairs = smacs0723_analog(seed=3).constellation()
    errs = estimator_errors(pairs, ("quad", "2v"))
    np.testing.assert_allclose(errs["frac_err_quad"], errs["mu_size_quad"] / pairs["mu_true"] - 1)
    noisy = estimator_errors(pairs, ("quad",), position_noise=0.05 * u.arcsec, seed=0)
    assert np.std(noisy["frac_err_quad"]) > np.std(errs["frac_err_quad"])
    with pytest.raises(ValueError, match="methods must be a non-empty list"):
        estimator_errors(pairs, ("quad3",))
    del pairs["mu_true"]
    with pytest.raises(ValueError, match="truth column 'mu_true'"):
        estimator_errors(pairs)


def test_validation_figures(grid):
    from lensdual.visualization import (
        plot_error_histograms,
        plot_estimator_grid,
        plot_true_vs_inferred,
    )

    fig = plot_estimator_grid(grid)
    assert len(fig.axes) == 4
    n_points = sum(len(c.get_offsets()) for c in fig.axes[0].collections)
    assert n_points == 3 * 10  # three methods, ten pairs in the top-left panel
    ax = plot_error_histograms(grid)
    assert len(ax.get_legend().get_texts()) == 3
    ax = plot_true_vs_inferred(grid, methods=("quad", "quad2"))
    assert "sd" in ax.get_legend().get_texts()[0].get_text()
    matplotlib.pyplot.close("all")

"""The tutorial's Python walk-through (docs/scripts/tutorial_api.py) runs and finds the sub-halo."""

import runpy
from pathlib import Path

import numpy as np

SCRIPT = Path(__file__).resolve().parents[1] / "docs" / "scripts" / "tutorial_api.py"


def test_tutorial_script_flags_only_the_subhaloed_pair(capsys):
    names = runpy.run_path(str(SCRIPT), run_name="tutorial")
    result, truth = names["result"], names["truth"]
    assert "anomalous" in capsys.readouterr().out
    assert len(result) == len(truth) == 12
    # match the measured pairs to the simulated sources by their L2 position
    from lensdual.simulation import lens_to_sky

    sky2 = lens_to_sky(np.column_stack([truth["x2"].value, truth["y2"].value]) * truth["x2"].unit)
    index, sep, _ = result["sky2"].match_to_catalog_sky(sky2)
    assert sep.arcsec.max() < 0.01
    assert sorted(index.tolist()) == list(range(12))
    flagged = np.asarray(result["anomalous"], dtype=bool)
    assert index[flagged].tolist() == [4]  # the source with the sub-halo, and only it
    smooth = np.asarray(names["smooth"]["mu_true"])[index]
    err = np.asarray(result["mu_size"]) / smooth - 1
    assert np.median(np.abs(err)) < 0.03

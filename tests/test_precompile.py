"""The second process that compiles the duality test's kernels ahead of need."""

import subprocess
import sys

import pytest

from lensdual import _precompile as precompile


@pytest.fixture
def nothing_pending():
    precompile.cancel()
    yield
    precompile.cancel()


@pytest.fixture
def uncached(nothing_pending, monkeypatch):
    """Two cores, the switch on and nothing cached: a second process is wanted."""
    monkeypatch.delenv(precompile.ENVIRONMENT, raising=False)
    monkeypatch.setattr(precompile, "_cached", lambda: False)
    monkeypatch.setattr(precompile, "_n_cores", lambda: 2)


def test_compile_kernels_leaves_the_estimator_in_the_cache(nothing_pending, monkeypatch):
    monkeypatch.setattr(precompile, "_n_cores", lambda: 2)
    precompile.compile_kernels("geometric", null_calibration=False)
    assert precompile._cached()
    assert not precompile.wanted()  # nothing left to compile ahead


@pytest.mark.parametrize("why", ["switched off", "one core", "cached"])
def test_nothing_starts_where_it_cannot_help(nothing_pending, monkeypatch, why):
    monkeypatch.setattr(precompile, "_cached", lambda: why == "cached")
    monkeypatch.setattr(precompile, "_n_cores", lambda: 1 if why == "one core" else 2)
    if why == "switched off":
        monkeypatch.setenv(precompile.ENVIRONMENT, "0")
    else:
        monkeypatch.delenv(precompile.ENVIRONMENT, raising=False)
    assert not precompile.wanted()
    precompile.start()
    assert precompile._pending is None
    assert precompile.wait() is None


def test_a_started_process_compiles_and_is_waited_for(uncached):
    assert precompile.wanted()
    precompile.start("geometric", null_calibration=False)
    proc = precompile._pending
    assert isinstance(proc, subprocess.Popen)
    precompile.start()  # one at a time
    assert precompile._pending is proc
    assert precompile.wait() == 0  # the kernels ran in that process without an error
    assert precompile._pending is None
    assert precompile.wait() is None


def test_cancel_stops_a_running_process(uncached):
    precompile.start("joint")
    proc = precompile._pending
    precompile.cancel()
    assert precompile._pending is None
    assert proc.poll() is not None  # stopped, not left running


def test_a_process_past_its_time_is_stopped(nothing_pending, monkeypatch):
    monkeypatch.setattr(precompile, "TIMEOUT_S", 0.01)
    monkeypatch.setattr(precompile, "_pending", subprocess.Popen(
        [sys.executable, "-c", "import time; time.sleep(30)"]))
    proc = precompile._pending
    status = precompile.wait()
    assert status is not None and status != 0
    assert proc.poll() is not None


def test_the_profile_kernels_compile_with_the_signatures_the_test_uses():
    """compile_profile_kernels compiles the two kernels that lensdual.duality's
    profile SNR calls, with the argument types it passes (one signature each,
    which a conservative check_duality then reuses rather than adding another)."""
    import astropy.units as u
    import numpy as np

    from lensdual import _precompile, _profile_kernels
    from lensdual.duality import check_duality
    from lensdual.simulation import clean_constellation, noisy_constellation

    _precompile.compile_profile_kernels()
    kernels = (_profile_kernels.whiten_all, _profile_kernels.profile_snr_whitened)
    before = [len(k.signatures) for k in kernels]
    assert all(n >= 1 for n in before)
    t = noisy_constellation(clean_constellation("cluster_fold", 12, seed=1),
                            sigma_pos=5 * u.mas, flux_rel_err=0.02, seed=1)
    result = check_duality(t, sigma_pos=5 * u.mas, snr_definition="conservative")
    assert np.isfinite(np.asarray(result["snr_profile"], dtype=float)).any()
    assert [len(k.signatures) for k in kernels] == before

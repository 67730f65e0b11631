"""Compile the duality test's Numba kernels in a second process, ahead of need.

The adaptive estimator's kernels take most of a first run's compilation
(about 20-30 s on one core), and a run needs them only after detection,
pairing and photometry. :func:`start` launches a Python process that
compiles them into Numba's on-disk cache (:func:`compile_kernels`) while the
calling process goes on with those first steps on another core;
:func:`wait`, called just before the estimator runs, waits for that process,
after which the kernels load from the cache.

Nothing is started where it cannot help: with the cache already written,
with the JIT disabled, on a single core, or when the environment variable
``LENSDUAL_PRECOMPILE`` is ``0``. Whatever the second process does, the
results are those of a run without it: it only fills the cache that the
calling process would have filled itself, and if it fails the calling
process compiles as usual.
"""

import os
import subprocess
import sys

__all__ = []

#: The environment variable that turns the second process off (value ``0``).
ENVIRONMENT = "LENSDUAL_PRECOMPILE"
#: Seconds :func:`wait` waits before it stops the second process.
TIMEOUT_S = 600.0

_pending = None


def _n_cores():
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _cached():
    """Whether Numba's cache already holds the adaptive estimator's kernel
    (False where that cannot be told)."""
    from .estimators._adaptive import adaptive_knn

    try:
        return os.path.exists(adaptive_knn._cache._cache_file._index_path)
    except AttributeError:  # Numba's cache internals differ: assume nothing cached
        return False


def wanted():
    """Whether a second compiling process would shorten this run."""
    from numba.core import config

    if os.environ.get(ENVIRONMENT, "1").strip() == "0" or config.DISABLE_JIT:
        return False
    return _n_cores() >= 2 and not _cached()


def start(test="auto", null_calibration=True, snr_definition="auto"):
    """Start the second process for the duality test ``test`` with the SNR
    ``snr_definition`` (and its null calibration) if :func:`wanted`; a no-op
    otherwise or when one is running."""
    global _pending
    if _pending is not None or not wanted():
        return
    code = (f"from lensdual._precompile import compile_kernels; "
            f"compile_kernels({test!r}, {bool(null_calibration)!r}, {snr_definition!r})")
    try:
        _pending = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.DEVNULL,
                                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except OSError:
        _pending = None


def running():
    """Whether a second process was started and not yet waited for."""
    return _pending is not None


def compile_profile_kernels():
    """Compile the profile-likelihood SNR's kernels here (one pair through
    :func:`lensdual.duality.profile_snr`, the call the test makes): what the
    first process does while it waits for the second, which leaves them out
    (see :func:`compile_kernels`)."""
    import numpy as np

    from .duality import profile_snr

    size = {"jacobian": np.array([[[1.2, 0.1], [0.05, -0.8]]]),
            "jacobian_cov": np.eye(4)[None] * 1e-4, "ln_mu_size_err": np.array([0.1])}
    profile_snr(size, np.array([0.0]), np.array([0.02]))


def wait():
    """Wait for the second process, if one was started (stopping it after
    :data:`TIMEOUT_S`); returns its exit status, or None when there was none."""
    global _pending
    proc, _pending = _pending, None
    if proc is None:
        return None
    try:
        return proc.wait(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()


def cancel():
    """Stop the second process if one is still running."""
    global _pending
    proc, _pending = _pending, None
    if proc is not None and proc.poll() is None:
        proc.kill()
        proc.wait()


def compile_kernels(test="auto", null_calibration=True, snr_definition="auto"):
    """Run the adaptive duality test ``test`` with the SNR ``snr_definition``
    (and a 100-realisation null
    calibration) on a small clean two-band constellation, so that every kernel
    they use is compiled and cached, with the argument types a run passes
    (per-source position errors on both arcs)."""
    import warnings

    import numpy as np
    from astropy import units as u
    from astropy.table import QTable

    from .duality import check_duality
    from .duality import null_calibration as run_null

    rng = np.random.default_rng(0)
    n = 16
    theta2 = rng.uniform(-1.0, 1.0, (n, 2))
    jac = np.array([[1.3, 0.2], [0.1, -0.7]])
    theta1 = theta2 @ jac.T + 0.05 * theta2 ** 2
    pairs = QTable()
    pairs["pair_id"] = np.arange(1, n + 1)
    for k, name in enumerate(("x", "y")):
        pairs[f"{name}1"] = theta1[:, k] * u.arcsec
        pairs[f"{name}2"] = theta2[:, k] * u.arcsec
    mu = abs(np.linalg.det(jac))
    for band in ("a", "b"):
        flux2 = rng.uniform(20.0, 40.0, n)
        pairs[f"flux1_{band}"] = flux2 * mu
        pairs[f"flux2_{band}"] = flux2
        pairs[f"flux_err1_{band}"] = 0.02 * flux2 * mu
        pairs[f"flux_err2_{band}"] = 0.02 * flux2
    pairs.meta["bands"] = ["a", "b"]
    sigma = np.full((2, n), 0.002) * u.arcsec
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # the linearised SNR: the profile SNR's kernels are compiled by the first
        # process while it waits for this one (lensdual.pipeline.analyse)
        check_duality(pairs, "adaptive", sigma_pos=sigma, test=test, seed=0,
                      snr_definition="log")
        if null_calibration:
            run_null(pairs, sigma_pos=sigma, n_realisations=100, seed=0, test=test,
                     snr_definition="log")

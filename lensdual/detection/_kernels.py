"""Numba kernels of the point-source filter chain (paper Appendix C).

Everything here works on plain arrays: ``float64`` images, ``bool``
validity maps and blurs and outputs of one float type (``float64``, or
``float32`` with ``PointSourceFilter(dtype="float32")``: each pixel is still
computed in float64 and rounded only when stored), all of the same 2-D shape
and C-contiguous. Bands come as
homogeneous tuples of arrays (one entry per band). No input validation happens
here; :mod:`lensdual.detection.core` does it, and also runs the Gaussian blurs
(`scipy.ndimage.gaussian_filter`) whose outputs are passed in.

Per band ``b`` the kernels see

* ``datas[b]``: the raw image (may hold NaN where the band is invalid);
* ``nums[b]``: the ``smooth_sigma`` blur of the raw image with invalid pixels
  set to 0;
* ``wblurs[b]``: the same blur of the validity map as ``float64`` (only read
  when ``masked[b]``), so that the smoothed image is ``nums[b] / wblurs[b]``
  (normalised convolution); when ``masked[b]`` is False the band has no
  invalid pixel, the smoothed image is ``nums[b]`` and ``wblurs[b]`` and
  ``valids[b]`` may be dummy ``(1, 1)`` arrays.

Two passes follow the blurs: :func:`band_statistics` (the per-band sums of the
positive part of the residual, and the co-added raw image that
the normalisation blur needs), then :func:`filter_pixels` (residual, flags,
composite mask, co-add, normalisation and threshold, in one sweep).
"""

import numpy as np
from numba import njit

__all__ = []

from .._numba import JIT_OPTIONS  # noqa: F401  (the package-wide options)


@njit(**JIT_OPTIONS)
def has_nonfinite(data):
    """True if the 2-D ``data`` holds any NaN or infinity."""
    ny, nx = data.shape
    for i in range(ny):
        for j in range(nx):
            v = data[i, j]
            if not (v - v == 0.0):
                return True
    return False


@njit(**JIT_OPTIONS)
def band_statistics(datas, nums, wblurs, valids, masked, any_masked, coadd, wcommon):
    """First pass: positive-residual sums per band and the co-added raw image.

    The residual of band ``b`` is ``r = data - smoothed`` at its valid pixels.

    Parameters
    ----------
    datas, nums, wblurs, valids : tuple of 2-D arrays
        See the module docstring.
    masked : (nb,) bool array
        Whether band ``b`` has invalid pixels.
    any_masked : bool
        ``masked.any()``; when True ``wcommon`` is written.
    coadd : (ny, nx) float64 array, output
        Sum over bands of the raw images where every band is valid, else 0.
    wcommon : float64 array, output
        1.0 where every band is valid, else 0.0 (shape (ny, nx); a dummy
        ``(1, 1)`` array, not written, when ``any_masked`` is False).

    Returns
    -------
    pos_sum : (nb,) float64 array
        Sums of ``max(r, 0)`` over the valid pixels.
    count : (nb,) int64 array
        Number of valid pixels.
    """
    nb = len(datas)
    ny, nx = coadd.shape
    pos_sum = np.zeros(nb)
    count = np.zeros(nb, dtype=np.int64)
    common = np.empty(nx, dtype=np.bool_)
    for i in range(ny):
        for j in range(nx):
            coadd[i, j] = 0.0
            common[j] = True
        for b in range(nb):
            data = datas[b]
            num = nums[b]
            pos = 0.0
            if masked[b]:
                valid = valids[b]
                wblur = wblurs[b]
                n = 0
                for j in range(nx):
                    if valid[i, j]:
                        d = data[i, j]
                        r = d - num[i, j] / wblur[i, j]
                        if r > 0.0:
                            pos += r
                        n += 1
                        coadd[i, j] += d
                    else:
                        common[j] = False
                count[b] += n
            else:
                for j in range(nx):
                    d = data[i, j]
                    r = d - num[i, j]
                    if r > 0.0:
                        pos += r
                    coadd[i, j] += d
                count[b] += nx
            pos_sum[b] += pos
        if any_masked:
            for j in range(nx):
                if common[j]:
                    wcommon[i, j] = 1.0
                else:
                    wcommon[i, j] = 0.0
                    coadd[i, j] = 0.0
    return pos_sum, count


@njit(**JIT_OPTIONS)
def filter_pixels(
    datas,
    nums,
    wblurs,
    valids,
    masked,
    flag_thresholds,
    norm_num,
    norm_w,
    any_masked,
    floor,
    snr_level,
    threshold,
    residuals,
    coadded,
    normalized,
    candidates,
):
    """Second pass: residual, flags, composite mask, co-add, normalise, threshold.

    Per pixel: ``r_b = max(data_b - smoothed_b, 0)`` at valid pixels (0
    elsewhere); the pixel is in the composite mask when ``r_b >
    flag_thresholds[b]`` in every band; there the co-added residual is
    ``sum_b r_b``, the denominator ``max(S, floor)`` with ``S = norm_num /
    norm_w`` (or ``norm_num`` when ``any_masked`` is False), and the
    normalised value their ratio (0 when the denominator is not positive).
    Outside the composite mask the co-add and the normalised value are 0. A
    pixel is a candidate when its normalised value exceeds ``threshold`` and
    its co-added residual exceeds ``snr_level``.

    Parameters
    ----------
    datas, nums, wblurs, valids, masked
        As in :func:`band_statistics`.
    flag_thresholds : (nb,) float64 array
        Flag level of each band (``threshold_factor`` times the band mean).
    norm_num, norm_w : 2-D float64 arrays
        Blur of the co-added raw image and of the common validity map
        (``norm_w`` is only read when ``any_masked``).
    any_masked : bool
    floor, snr_level, threshold : float
    residuals : tuple of (ny, nx) float64 arrays, output
        The positive residual of each band. ``residuals[b]`` may be
        ``nums[b]`` (overwritten in place).
    coadded, normalized : (ny, nx) float64 arrays, output
        ``coadded`` may be ``norm_num`` (overwritten in place);
        ``normalized`` must not share memory with any input.
    candidates : (ny, nx) bool array, output
    """
    nb = len(datas)
    ny, nx = coadded.shape
    composite = np.empty(nx, dtype=np.bool_)
    total = np.empty(nx)
    for i in range(ny):
        for j in range(nx):
            composite[j] = True
            total[j] = 0.0
        for b in range(nb):
            data = datas[b]
            num = nums[b]
            res = residuals[b]
            level = flag_thresholds[b]
            if masked[b]:
                valid = valids[b]
                wblur = wblurs[b]
                for j in range(nx):
                    r = 0.0
                    if valid[i, j]:
                        r = data[i, j] - num[i, j] / wblur[i, j]
                        if r < 0.0:
                            r = 0.0
                    res[i, j] = r
                    composite[j] = composite[j] and r > level
                    total[j] += r
            else:
                for j in range(nx):
                    r = data[i, j] - num[i, j]
                    if r < 0.0:
                        r = 0.0
                    res[i, j] = r
                    composite[j] = composite[j] and r > level
                    total[j] += r
        for j in range(nx):
            if composite[j]:
                t = total[j]
                if any_masked:
                    s = norm_num[i, j] / norm_w[i, j]
                else:
                    s = norm_num[i, j]
                den = s if s > floor else floor
                v = t / den if den > 0.0 else 0.0
                coadded[i, j] = t
                normalized[i, j] = v
                candidates[i, j] = v > threshold and t > snr_level
            else:
                coadded[i, j] = 0.0
                normalized[i, j] = 0.0
                candidates[i, j] = False

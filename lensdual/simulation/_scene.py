"""The messy parts of the realistic mock scene: host clumps, a member, ICL, a diffuse patch.

* **Clumps of the host** (``clumps=``): many faint, small round Gaussians in
  the source plane, scattered about the host's centre, added to the host's
  lenstronomy light model and ray-traced with it on the renderer's
  sub-pixels. Ray tracing, not the local map of the star clusters
  (``_clusters.py``): a clump is not at a constellation's source position,
  so it has no image positions to linearise about, and ray tracing gives
  its images on both arcs (and where they fall) without solving the lens
  equation. The default clumps have source-plane standard deviations of
  15-40 mas, larger than the 8 mas sub-pixels, so the ray-traced images
  are resolved (the clusters, 0.1-6 mas, are not). Their fluxes are set so
  that no clump reaches the detection threshold.
* **A cluster member** (``member=``): an elliptical Sérsic (lenstronomy
  ``SERSIC_ELLIPSE``) in the image plane, not lensed, convolved with the
  PSF, placed at an offset from one arc.
* **Intracluster light** (``icl=``): on one arc's cutouts only, an
  exponential gradient ``S0 exp(u . (x - c) / h)`` of the surface
  brightness (``S0`` at the arc's centre ``c``, scale length ``h``,
  brightening along the unit vector ``u``, by default towards the lens
  centre), integrated over each pixel in closed form and not convolved (a
  normalised PSF changes an exponential of scale ``h`` >> PSF by a factor
  ``1 + O((FWHM / h)**2)``).
* **A diffuse patch** (``patch=``): a round Gaussian in the image plane
  (lenstronomy ``GAUSSIAN``), convolved with the PSF, centred on one image
  of one chosen pair (as under image 2.1, on arc 2, of the paper's pair 1);
  the truth table records which (columns ``patch1``, ``patch2``) and its
  flux per band (``meta['patch_flux']``, nJy). Its flux is given either in
  nJy or as a ``contrast``: the patch's flux that an amplitude-only fit of
  the pixel PSF, centred on the image, takes up, as a multiple of the
  image's own flux (:func:`patch_leak`).
"""

from collections.abc import Mapping

import numpy as np
from astropy import units as u

from .._validation import as_angle_scalar, as_int, as_real

__all__ = ["MOCK_CLUMPS", "MOCK_ICL", "MOCK_MEMBER", "MOCK_PATCH"]

#: The default clumps of the host (``clumps=True``): ``n`` round Gaussians,
#: source-plane positions drawn normally about the host's centre with
#: standard deviation ``spread``, standard deviations log-uniform in
#: ``sigma`` and unlensed fluxes log-uniform in ``flux`` (nJy, the same in
#: every band).
MOCK_CLUMPS = {
    "n": 40,
    "flux": (0.03 * u.nJy, 0.12 * u.nJy),
    "sigma": (0.015 * u.arcsec, 0.04 * u.arcsec),
    "spread": 0.3 * u.arcsec,
}

#: The default cluster member (``member=True``): a Sérsic of total flux
#: ``flux`` (23.1 AB), half-light radius ``R_sersic``, index ``n_sersic``
#: and ellipticity ``e1``, ``e2``, centred at ``offset`` from the centre of
#: arc ``arc``.
MOCK_MEMBER = {
    "flux": 2000.0 * u.nJy,
    "R_sersic": 0.3 * u.arcsec,
    "n_sersic": 4.0,
    "e1": 0.1,
    "e2": -0.05,
    "arc": "L2",
    "offset": [1.2, 0.8] * u.arcsec,
}

#: The default intracluster light (``icl=True``): ``surface_brightness`` at
#: the centre of arc ``arc`` (300 nJy/arcsec^2, 25.3 AB mag/arcsec^2),
#: brightening by e per ``scale_length`` towards ``direction`` (an angle
#: from the lens frame's +x axis towards +y; None: towards the lens centre).
MOCK_ICL = {
    "surface_brightness": 300.0 * u.nJy / u.arcsec ** 2,
    "scale_length": 2.0 * u.arcsec,
    "arc": "L1",
    "direction": None,
}

#: The default diffuse patch (``patch=True``): a round Gaussian of
#: standard deviation ``sigma`` under the image on arc ``arc`` of row
#: ``pair`` of the pairs table. Its total flux is ``flux`` (nJy, a Quantity
#: or a dict per band) or, where ``flux`` is None, set per band so that a
#: PSF fit of the image's amplitude without background would take up
#: ``contrast`` times the image's flux from the patch (:func:`patch_leak`):
#: contrast 1 doubles the image's flux to such a fit, as the diffuse
#: emission under image 2.1 of the paper's pair 1 did (a flux ratio of
#: about 0.5 against a size magnification of 1.04).
MOCK_PATCH = {
    "flux": None,
    "contrast": 1.0,
    "sigma": 0.12 * u.arcsec,
    "pair": 0,
    "arc": "L2",
}

_ARCS = ("L1", "L2")


def options(value, defaults, name):
    """None (off) or the defaults updated with the user's dict."""
    if value is None or value is False:
        return None
    if value is True:
        value = {}
    if not isinstance(value, Mapping):
        raise TypeError(f"{name} must be True, False, None or a dict, got "
                        f"{type(value).__name__}")
    unknown = sorted(set(value) - set(defaults))
    if unknown:
        raise ValueError(f"{name} has unknown key(s) {unknown}; allowed: {sorted(defaults)}")
    return {**defaults, **value}


def _flux(value, name, bands, unit=u.nJy):
    """Per band, a non-negative flux (or surface brightness) in ``unit``."""
    def one(v, label):
        if not isinstance(v, u.Quantity) or not v.isscalar:
            raise TypeError(f"{label} must be a scalar Quantity in {unit}, got {v!r}")
        try:
            x = float(v.to_value(unit))
        except u.UnitsError:
            raise TypeError(f"{label} must have units convertible to {unit}, got {v.unit!s}"
                            ) from None
        if not (np.isfinite(x) and x >= 0):
            raise ValueError(f"{label} must be finite and >= 0, got {v}")
        return x

    return per_band(value, bands, name, one)


def per_band(value, bands, name, convert):
    """``{band: convert(value_for_band, label)}`` from a scalar or a dict per band."""
    if isinstance(value, Mapping):
        missing = [b for b in bands if b not in value]
        if missing:
            raise ValueError(f"{name} lacks band(s) {missing}")
        return {b: convert(value[b], f"{name}[{b!r}]") for b in bands}
    return {b: convert(value, name) for b in bands}


def _arc(value, name):
    if value not in _ARCS:
        raise ValueError(f"{name} must be 'L1' or 'L2', got {value!r}")
    return value


def _offset(value, name):
    if not isinstance(value, u.Quantity) or value.shape != (2,) \
            or value.unit.physical_type != "angle":
        raise TypeError(f"{name} must be an angle Quantity of shape (2,), got {value!r}")
    v = value.to_value(u.arcsec).astype(np.float64)
    if not np.isfinite(v).all():
        raise ValueError(f"{name} must be finite")
    return v


def _range(value, name, unit, positive=True):
    if not (isinstance(value, (tuple, list)) and len(value) == 2):
        raise TypeError(f"{name} must be a pair (low, high) of Quantities, got {value!r}")
    lo, hi = (as_angle_scalar(v, f"{name}[{k}]", allow_zero=not positive) if unit is u.arcsec
              else _flux(v, f"{name}[{k}]", ["_"])["_"] for k, v in enumerate(value))
    if lo > hi or (positive and lo <= 0):
        raise ValueError(f"{name} must satisfy 0 < low <= high, got {value!r}")
    return lo, hi


def member_params(member, bands):
    """None, or the checked member: fluxes per band, lenstronomy shape, arc, offset."""
    p = options(member, MOCK_MEMBER, "member")
    if p is None:
        return None
    return {"flux": _flux(p["flux"], "member['flux']", bands),
            "R_sersic": as_angle_scalar(p["R_sersic"], "member['R_sersic']", allow_zero=False),
            "n_sersic": as_real(p["n_sersic"], "member['n_sersic']", minimum=0.2, maximum=8.0),
            "e1": as_real(p["e1"], "member['e1']", minimum=-0.9, maximum=0.9),
            "e2": as_real(p["e2"], "member['e2']", minimum=-0.9, maximum=0.9),
            "arc": _arc(p["arc"], "member['arc']"),
            "offset": _offset(p["offset"], "member['offset']")}


def icl_params(icl, bands):
    """None, or the checked ICL gradient."""
    p = options(icl, MOCK_ICL, "icl")
    if p is None:
        return None
    direction = p["direction"]
    if direction is not None:
        if not (isinstance(direction, u.Quantity) and direction.isscalar
                and direction.unit.physical_type == "angle"):
            raise TypeError(f"icl['direction'] must be None or a scalar angle Quantity, got "
                            f"{direction!r}")
        direction = as_real(direction.to_value(u.rad), "icl['direction']")
    return {"sb": _flux(p["surface_brightness"], "icl['surface_brightness']", bands,
                        u.nJy / u.arcsec ** 2),
            "h": as_angle_scalar(p["scale_length"], "icl['scale_length']", allow_zero=False),
            "arc": _arc(p["arc"], "icl['arc']"), "direction": direction}


def patch_params(patch, bands, n_rows):
    """None, or the checked diffuse patch."""
    p = options(patch, MOCK_PATCH, "patch")
    if p is None:
        return None
    pair = as_int(p["pair"], "patch['pair']", minimum=0)
    if pair >= n_rows:
        raise ValueError(f"patch['pair'] must be a row of the pairs table (0 to {n_rows - 1}), "
                         f"got {pair}")
    given = patch if isinstance(patch, Mapping) else {}
    if given.get("flux") is not None and given.get("contrast") is not None:
        raise ValueError("patch takes 'flux' or 'contrast', not both (with a flux, set "
                         "'contrast': None)")
    out = {"sigma": as_angle_scalar(p["sigma"], "patch['sigma']", allow_zero=False),
           "pair": pair, "arc": _arc(p["arc"], "patch['arc']"), "flux": None,
           "contrast": None}
    if p["flux"] is not None:
        out["flux"] = _flux(p["flux"], "patch['flux']", bands)
    elif p["contrast"] is None:
        raise ValueError("patch needs a 'flux' or a 'contrast'")
    else:
        out["contrast"] = per_band(p["contrast"], bands, "patch['contrast']",
                                   lambda v, label: as_real(v, label, minimum=0.0))
    return out


def patch_leak(pixel_kernel, sigma):
    """The share of a round Gaussian's flux that an amplitude-only PSF fit takes up.

    A least-squares fit of ``A P`` (``P`` the pixel PSF, centred on the
    image) to the patch's pixels ``G * P`` (``G`` the pixel-integrated
    Gaussian of standard deviation ``sigma`` pixels, of unit flux, centred
    there too) gives ``A = <P, G * P> / <P, P>``.
    """
    from scipy.signal import fftconvolve
    from scipy.special import erf

    k = np.asarray(pixel_kernel, dtype=np.float64)
    k = k / k.sum()
    half = int(np.ceil(6 * sigma))
    edges = (np.arange(-half, half + 2) - 0.5) / (np.sqrt(2) * sigma)
    g1 = 0.5 * np.diff(erf(edges))
    patch = fftconvolve(np.outer(g1, g1), k, mode="full")
    # the kernel's footprint within the patch image, both centred on the same pixel
    n, m = k.shape[0], patch.shape[0]
    lo = (m - n) // 2
    return float((k * patch[lo:lo + n, lo:lo + n]).sum() / (k * k).sum())


def resolve_patch_flux(patch, image_flux, pixel_kernels, pixel_scale):
    """The patch with its ``flux`` per band set from its ``contrast``.

    ``image_flux`` is ``{band: flux of the image under the patch}`` (nJy),
    ``pixel_kernels`` each band's PSF at the pixel scale (odd-sized, centred).
    """
    if patch["flux"] is not None:
        return patch
    sigma = patch["sigma"] / pixel_scale
    flux = {b: patch["contrast"][b] * float(image_flux[b])
            / patch_leak(pixel_kernels[b], sigma) for b in patch["contrast"]}
    return {**patch, "flux": flux}


def clump_params(clumps):
    """None, or the checked clump options."""
    p = options(clumps, MOCK_CLUMPS, "clumps")
    if p is None:
        return None
    return {"n": as_int(p["n"], "clumps['n']", minimum=0),
            "flux": _range(p["flux"], "clumps['flux']", u.nJy),
            "sigma": _range(p["sigma"], "clumps['sigma']", u.arcsec),
            "spread": as_angle_scalar(p["spread"], "clumps['spread']")}


def draw_clumps(p, centre, rng):
    """The clumps' lenstronomy ``GAUSSIAN`` kwargs (``amp`` = unlensed flux, nJy)."""
    n = p["n"]
    xy = centre + p["spread"] * rng.standard_normal((n, 2))
    sigma = np.exp(rng.uniform(*np.log(p["sigma"]), n))
    flux = np.exp(rng.uniform(*np.log(p["flux"]), n))
    return [{"amp": float(f), "sigma": float(s), "center_x": float(x), "center_y": float(y)}
            for f, s, (x, y) in zip(flux, sigma, xy, strict=True)]


def image_plane_kwargs(member, patch, arc_centres, pos, band):
    """lenstronomy light kwargs ``(profiles, kwargs)`` of the member and the patch in one band."""
    from lenstronomy.LightModel.light_model import LightModel

    profiles, kwargs = [], []
    if member is not None:
        centre = arc_centres[member["arc"]] + member["offset"]
        shape = {"R_sersic": member["R_sersic"], "n_sersic": member["n_sersic"],
                 "e1": member["e1"], "e2": member["e2"],
                 "center_x": float(centre[0]), "center_y": float(centre[1])}
        unit = LightModel(["SERSIC_ELLIPSE"]).total_flux([{**shape, "amp": 1.0}])[0]
        profiles.append("SERSIC_ELLIPSE")
        kwargs.append({**shape, "amp": member["flux"][band] / unit})
    if patch is not None:
        x, y = pos[patch["arc"]][patch["pair"]]
        profiles.append("GAUSSIAN")
        kwargs.append({"amp": patch["flux"][band], "sigma": patch["sigma"],
                       "center_x": float(x), "center_y": float(y)})
    return profiles, kwargs


def icl_image(icl, band, arc_centre, origin, scale, n):
    """The ICL gradient on one cutout (nJy per pixel), pixel-integrated in closed form."""
    if icl["direction"] is None:
        d = -np.asarray(arc_centre, dtype=np.float64)
        norm = np.hypot(*d)
        d = np.array([1.0, 0.0]) if norm == 0 else d / norm
    else:
        d = np.array([np.cos(icl["direction"]), np.sin(icl["direction"])])
    h = icl["h"]
    centres = origin[:, None] + scale * np.arange(n)[None, :]  # (2, n): x and y centres
    ex = np.exp(d[0] * (centres[0] - arc_centre[0]) / h)
    ey = np.exp(d[1] * (centres[1] - arc_centre[1]) / h)
    # the integral of exp(k t) over a pixel of side a, centred on 0: a sinh(k a/2) / (k a/2)
    fx, fy = (_sinhc(di * scale / (2 * h)) for di in d)
    return icl["sb"][band] * scale ** 2 * fx * fy * np.outer(ey, ex)


def _sinhc(z):
    return 1.0 if z == 0 else float(np.sinh(z) / z)

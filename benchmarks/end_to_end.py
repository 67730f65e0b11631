"""End to end on one mock: simulate, render, detect, pair, measure, test duality.

The SMACS0723 analogue with its two cluster members and an over-concentrated
1e8 Msun sub-halo (c = 100) on the L2 image of one point source (pair 5), a
resolvable constellation of 12 sources (jittered grid), two-band mocks, then
the real-data pipeline with no truth: find_point_sources, psf_photometry,
pair_constellations (automatic), measure_pairs, check_duality with sigma_pos
from the PSF fits. A prototype of ``lensdual demo``::

    python benchmarks/end_to_end.py

Found when it was written (seed 0, 6.6 s): mu_flux matches the truth to a few
per cent. With the Quad estimator the sub-haloed pair stands out (SNR ~25)
but 7 clean pairs are flagged too (SNR 3-9): with PSF-fit astrometry at the
mas level the bootstrap error of mu_size is far below the Quad estimator's
own systematic error on 12 sources. With the second-order fit ("quad2")
only the sub-haloed pair is flagged (SNR 23; all others below 2).
"""

import time
import warnings

import astropy.units as u
import numpy as np
from astropy.table import QTable

from lensdual.detection import find_point_sources
from lensdual.duality import check_duality
from lensdual.pairing import pair_constellations
from lensdual.photometry import measure_pairs, psf_photometry
from lensdual.simulation import render_mock_images, smacs0723_analog, tnfw_halo

BANDS = ("F150W", "F200W")


def simulate(seed=0, subhalo_pair=4):
    """The analogue with members, a 12-source grid and a sub-halo on one L2 image."""
    rng = np.random.default_rng(seed)
    base = smacs0723_analog(perturbers=True, seed=seed)
    gx, gy = np.meshgrid([0.35, 0.65, 0.95], [6.70, 6.82, 6.94, 7.06])
    beta = np.column_stack([gx.ravel(), gy.ravel()]) + rng.uniform(-0.02, 0.02, (12, 2))
    f0 = 10 ** rng.uniform(np.log10(3.0), 1.0, 12)
    flux = {"F150W": f0, "F200W": 0.9 * f0}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        before = base.constellation(beta * u.arcsec, intrinsic_flux=flux)
    host = np.array([before["x2"][subhalo_pair].value, before["y2"][subhalo_pair].value])
    sub = tnfw_halo(1e8 * u.Msun, 100, (host + [0.002, 0.0]) * u.arcsec, z_lens=0.39,
                    z_source=2.2, label="over-concentrated sub-halo")
    system = base.add(sub)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        truth = system.constellation(beta * u.arcsec, intrinsic_flux=flux)
    return system, truth


def catalogue(images):
    """Detections of one arc with their PSF fluxes per band (no truth used)."""
    cat = find_point_sources(images)
    out = QTable({"id": cat["id"], "sky": cat["sky_centroid"]})
    xy = np.column_stack([cat["x_centroid"], cat["y_centroid"]])
    for band in images:
        out[f"flux_{band}"] = psf_photometry(images[band], xy, warn=False)["flux"]
    return out


def main():
    start = time.perf_counter()
    system, truth = simulate()
    mocks = render_mock_images(system, pairs=truth, seed=0)
    cats = {arc: catalogue(mocks.arc(arc)) for arc in ("L1", "L2")}
    pairs = pair_constellations(cats["L1"], cats["L2"], position_columns="sky",
                                flux_columns=[f"flux_{b}" for b in BANDS], seed=0)
    measured = measure_pairs(mocks.arc("L1"), mocks.arc("L2"), pairs)
    sigma = np.vstack([measured["pos_err1"].to_value(u.arcsec),
                       measured["pos_err2"].to_value(u.arcsec)]) * u.arcsec
    for method in ("quad", "quad2"):
        result = check_duality(measured, method, sigma_pos=sigma, seed=0)
        for name in ("mu_flux", "mu_size", "mu_size_err", "snr"):
            result[name].info.format = ".3f"
        print(f"\nmethod {method!r}:")
        result["pair_id", "id1", "id2", "mu_flux", "mu_size", "mu_size_err", "snr",
               "anomalous"].pprint(max_lines=-1)
    print(f"true |mu(L1)/mu(L2)|, in the simulation's source order: "
          f"{np.round(np.asarray(truth['mu_true']), 3)}")
    print(f"total {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()

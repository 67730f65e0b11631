"""The demo's steps from Python, with the public API (the tutorial's second part).

Run it as it is (``python docs/scripts/tutorial_api.py``); the tests run it too.
"""

import warnings

import astropy.units as u
import numpy as np
from astropy.table import QTable

from lensdual.detection import find_point_sources
from lensdual.duality import check_duality
from lensdual.pairing import pair_constellations
from lensdual.photometry import measure_pairs, psf_photometry
from lensdual.simulation import render_mock_images, smacs0723_analog, tnfw_halo

# 1. The lens: the SMACS0723 analogue with its two cluster members, and a
#    resolvable constellation of 12 point sources in the source plane.
rng = np.random.default_rng(0)
lens = smacs0723_analog(perturbers=True)
gx, gy = np.meshgrid([0.35, 0.65, 0.95], [6.70, 6.82, 6.94, 7.06])
beta = (np.column_stack([gx.ravel(), gy.ravel()]) + rng.uniform(-0.02, 0.02, (12, 2))) * u.arcsec
flux = {"F150W": 10 ** rng.uniform(0.5, 1.0, 12)}
flux["F200W"] = 0.9 * flux["F150W"]
with warnings.catch_warnings():
    warnings.simplefilter("ignore")  # the weak third images are far from the arcs
    smooth = lens.constellation(beta, intrinsic_flux=flux)

# 2. An over-concentrated 1e8 Msun sub-halo 2 mas from the L2 image of source 4.
host = u.Quantity([smooth["x2"][4], smooth["y2"][4]]) + [0.002, 0.0] * u.arcsec
subhalo = tnfw_halo(1e8 * u.Msun, 100, host, z_lens=0.39, z_source=2.2)
system = lens.add(subhalo)
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    truth = system.constellation(beta, intrinsic_flux=flux)

# 3. Two-band mock JWST images of both arcs (CCDData with WCS, errors and PSF).
mocks = render_mock_images(system, pairs=truth, seed=0)
psf = {band: mocks[("L1", band)].psf for band in mocks.bands}


# 4. Detect the point sources on each arc and measure their fluxes (for colours).
def catalogue(images):
    found = find_point_sources(images)
    cat = QTable({"id": found["id"], "sky": found["sky_centroid"]})
    xy = np.column_stack([found["x_centroid"], found["y_centroid"]])
    for band, image in images.items():
        cat[f"flux_{band}"] = psf_photometry(image, xy, psf=psf[band], warn=False)["flux"]
    return cat


cat1, cat2 = catalogue(mocks.arc("L1")), catalogue(mocks.arc("L2"))

# 5. Pair the two constellations automatically (positions and colours).
pairs = pair_constellations(cat1, cat2, position_columns="sky",
                            flux_columns=["flux_F150W", "flux_F200W"], seed=0)

# 6. PSF photometry of the pairs: fluxes and refined positions in one frame.
measured = measure_pairs(mocks.arc("L1"), mocks.arc("L2"), pairs, psf=psf)

# 7. Size magnification (the adaptive estimator, whose errors include its own
#    truncation error) from each source's positional error of the PSF fits,
#    and the calibrated duality test.
sigma = u.Quantity([measured["pos_err1"], measured["pos_err2"]])
result = check_duality(measured, sigma_pos=sigma)
for name in ("mu_flux", "mu_size", "mu_size_err", "snr", "p_value"):
    result[name].info.format = ".3g"
result["pair_id", "mu_flux", "mu_size", "mu_size_err", "snr", "p_value", "tested",
       "anomalous"].pprint(max_lines=-1)
print(f"{result.meta['duality']['n_flagged']} flagged of {result.meta['duality']['n_tested']}; "
      f"expected without a sub-halo: {result.meta['duality']['expected_false_flags']:.2f}")

if __name__ == "__main__":
    import matplotlib.pyplot as plt

    from lensdual.visualization import plot_duality

    plot_duality(result)
    plt.show()

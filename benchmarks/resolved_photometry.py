"""The flux ratios of slightly resolved star clusters: PSF photometry against the resolved fit.

Run on demand (about an hour of CPU)::

    python benchmarks/resolved_photometry.py [--reps 120] [--seeds 30] \
        [--output docs/_static/scenes/resolved_photometry.txt]

Part 1, stamps at the stretches of cluster arcs (|mu_t| 10-30, beyond the
demo's 2-8): a fold pair of images of one round Gaussian cluster of
half-light radius r_eff (0, 1, 5, 10, 20 pc; 1 pc = 0.121 mas at z = 2.2),
each image the cluster through its local lens map ``A_i^-1 = R diag(+-mu_t,
mu_r) R^T`` (mu_r = 1.3, the arc 29 degrees from the x axis, opposite
tangential parities), rendered by the realistic scene's cluster renderer
(``lensdual.simulation._clusters``: the ellipse convolved with the PSF in
Fourier space) with the demo's F150W pixel (0.04 arcsec) and Gaussian PSF
(FWHM 0.05 arcsec), on a flat background of 0.5 nJy per pixel with Gaussian
noise of 0.13 nJy per pixel (the demo's sky-limited noise). The cluster has
1.5 nJy unlensed (a point source's S/N is 40-160 on these images). Each
image is measured from a start 0.2 pixel off:

* ``point``: :func:`~lensdual.photometry.psf_photometry` with the PSF (a
  fitted plane under the source, a 9 x 9 box), today's photometry;
* ``resolved``: the same with ``source_model="resolved"``: each image alone,
  the PSF convolved with an elliptical Gaussian of free covariance;
* ``joint``: a reference that the package does not offer: both images
  fitted together with one shared shape, image 1's covariance tied to image
  2's through the true relative Jacobian ``J = A_1^-1 A_2``
  (``C_1 = J C_2 J^T``).

Reported per radius and pair of stretches: the median ln(mu_flux /
mu_true) over the realisations (bias), its standard deviation, and the
width of the pulls ln(mu_flux / mu_true) / sigma (16-84 % half-width), with
sigma from the fits' flux errors (the joint fit's from its covariance of
both fluxes). Then what each fit makes of a true anomaly: image 1's
tangential magnification 1.3 times the map's (a sub-halo), with the
``joint`` fit given the map's J (what the constellation would give): the
median of the measured ln(mu_flux / mu_true), 0 when the anomaly is kept
whole, -0.26 when it is lost.

Part 2, the demo (``benchmarks/finite_size_bias.py``'s part 1: the demo lens
without sub-halo, 12 sources x 2 bands, clusters of one r_eff, stretches
2-8) measured with ``measure_pairs`` both ways: the median ln(mu_flux /
mu_true), its 16-84 % half-width and the pulls' width.
"""

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from _output import Record, add_output_argument
from astropy.nddata import NDData, StdDevUncertainty

from lensdual.photometry import psf_photometry
from lensdual.photometry._background import _PolyBasis
from lensdual.photometry._profiles import _GaussianProfile
from lensdual.photometry._resolved import _FineKernel, fit_resolved, make_stamp, psf_variance
from lensdual.simulation._clusters import cluster_images
from lensdual.simulation.mock import _gaussian_kernel

sys.path.insert(0, str(Path(__file__).resolve().parent))
import finite_size_bias  # noqa: E402

SCALE = 0.04  # arcsec per pixel
FWHM = 0.05  # arcsec, F150W
SUPERSAMPLING = 5
N_PIX = 25
MAS_PER_PC = 0.121  # at z = 2.2 (flat LCDM 70 / 0.3)
HALF_LIGHT_PER_SIGMA = 1.1774
MU_R = 1.3
ARC_ANGLE = 0.5  # radians
FLUX0 = 1.5  # nJy, unlensed
NOISE = 0.13  # nJy per pixel
FIT_SHAPE = (9, 9)
RADII = (0.0, 1.0, 5.0, 10.0, 20.0)
STRETCHES = ((20.0, 10.0), (30.0, 15.0), (30.0, 10.0))
ANOMALY = 1.3


def _rot(phi):
    c, s = np.cos(phi), np.sin(phi)
    return np.array([[c, -s], [s, c]])


def inverse_jacobian(mu_t, parity):
    """``A^-1`` of an image stretched mu_t times along the arc, MU_R across it."""
    r = _rot(ARC_ANGLE)
    return r @ np.diag([parity * mu_t, MU_R]) @ r.T


class Stamps:
    """Renders the images of one cluster and measures them three ways."""

    def __init__(self):
        self.kernel = _gaussian_kernel(FWHM, SCALE, SUPERSAMPLING)
        self.origin = np.full(2, -(N_PIX // 2) * SCALE)
        profile = _GaussianProfile(FWHM / SCALE, None)
        self.fine = _FineKernel(profile, FIT_SHAPE[0] // 2 + 3, 1.5 * (FIT_SHAPE[0] // 2))
        self.p2 = psf_variance(profile)

    def render(self, a_inv, sigma, rng):
        """One noisy image of the cluster (covariance sigma^2 A^-1 A^-T) and its pixel
        position."""
        xy = np.array([[0.003, -0.011]])
        flux = FLUX0 * abs(np.linalg.det(a_inv))
        cov = sigma**2 * a_inv @ a_inv.T
        img = cluster_images(xy, np.array([flux]), cov[None], kernel=self.kernel,
                             kernel_supersampling=SUPERSAMPLING, origin=self.origin,
                             scale=SCALE, n=N_PIX)[0]
        img = img + 0.5 + rng.normal(0.0, NOISE, img.shape)
        return img, (xy[0] - self.origin) / SCALE

    def measure(self, images, jac):
        """ln flux ratio and its error, per method, of the two images (image, position)."""
        out = {}
        for model in ("point", "resolved"):
            f, e = [], []
            for img, pos in images:
                nd = NDData(img, uncertainty=StdDevUncertainty(np.full(img.shape, NOISE)))
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    t = psf_photometry(nd, [(pos[0] + 0.2, pos[1] - 0.2)], psf=FWHM / SCALE,
                                       background="plane", fit_shape=FIT_SHAPE,
                                       source_model=model)
                f.append(float(t["flux"][0]))
                e.append(float(t["flux_err"][0]))
            out[model] = (np.log(f[0] / f[1]), np.hypot(e[0] / f[0], e[1] / f[1]))
        stamps = [make_stamp(img, np.full(img.shape, NOISE), None, pos[0] + 0.2, pos[1] - 0.2,
                             FIT_SHAPE, _PolyBasis(1), self.fine, 2.0)
                  for img, pos in images]
        fit = fit_resolved(stamps, [jac, np.eye(2)], self.p2)
        g = np.array([1.0 / fit.flux[0], -1.0 / fit.flux[1]])
        out["joint"] = (np.log(fit.flux[0] / fit.flux[1]), float(np.sqrt(g @ fit.flux_cov @ g)))
        return out

    def run(self, r_pc, mu1, mu2, reps, seed, anomaly=1.0):
        """Per method: (median bias, sd, pull width) over ``reps`` realisations."""
        rng = np.random.default_rng(seed)
        a1 = inverse_jacobian(mu1 * anomaly, +1)
        a1_map = inverse_jacobian(mu1, +1)
        a2 = inverse_jacobian(mu2, -1)
        jac = a1_map @ np.linalg.inv(a2)
        sigma = r_pc * MAS_PER_PC / 1e3 / HALF_LIGHT_PER_SIGMA
        true = np.log(abs(np.linalg.det(a1) / np.linalg.det(a2)))
        got = {}
        for _ in range(reps):
            images = [self.render(a1, sigma, rng), self.render(a2, sigma, rng)]
            for k, v in self.measure(images, jac).items():
                got.setdefault(k, []).append(v)
        rows = {}
        for k, v in got.items():
            v = np.array(v)
            d = v[:, 0] - true
            q16, q84 = np.percentile(d / v[:, 1], [16, 84])
            rows[k] = (float(np.median(d)), float(np.std(d)), float(0.5 * (q84 - q16)))
        return rows


def stamp_table(rec, reps):
    """Part 1."""
    bench = Stamps()
    rec.say(f"1. Stamps: a fold pair of one cluster, {reps} noise realisations per row, "
            f"pixel {SCALE} arcsec, Gaussian PSF FWHM {FWHM} arcsec, noise {NOISE} nJy/pixel;")
    rec.say("   bias = median ln(mu_flux/mu_true), sd its scatter, pull = 16-84 % half-width "
            "of the pulls")
    rec.say("")
    rec.say(" r_eff  mu_t   mu_t |       point (today)     |       resolved          |"
            "   joint (reference)")
    rec.say("  [pc]    L1     L2 |   bias     sd    pull  |   bias     sd    pull  |"
            "   bias     sd    pull")
    seed = 0
    for r in RADII:
        for mu1, mu2 in STRETCHES:
            rows = bench.run(r, mu1, mu2, reps, seed)
            seed += 1
            cells = "|".join(f" {b:+7.4f} {sd:6.4f} {pw:6.2f}  "
                             for b, sd, pw in (rows[k] for k in ("point", "resolved", "joint")))
            rec.say(f"{r:6.0f} {mu1:5.0f} {mu2:6.0f} |{cells}")
    rec.say("")
    rec.say(f"   A true anomaly: image 1's tangential magnification x {ANOMALY} "
            f"(ln {np.log(ANOMALY):.3f}), the joint fit given the map's J;")
    rec.say("   median ln(mu_flux/mu_true): 0 keeps the anomaly whole")
    rec.say("")
    rec.say(" r_eff  mu_t   mu_t |  point   resolved  joint")
    for r in (5.0, 20.0):
        rows = bench.run(r, 20.0, 10.0, max(reps // 2, 10), 1000 + int(r), anomaly=ANOMALY)
        rec.say(f"{r:6.0f} {20:5d} {10:6d} | " + "  ".join(
            f"{rows[k][0]:+7.4f}" for k in ("point", "resolved", "joint")))


def demo_table(rec, seeds):
    """Part 2."""
    rec.say("")
    rec.say(f"2. The demo lens (stretches 2-8), 12 sources x {len(seeds)} seeds "
            f"{list(seeds)} x 2 bands, measure_pairs from the true positions:")
    rec.say("")
    rec.say(" r_eff |        point (today)        |          resolved")
    rec.say("  [pc] |  median  16-84%/2    pull   |  median  16-84%/2    pull   pairs")
    point = finite_size_bias.photometry_bias(seeds, "point")
    resolved = finite_size_bias.photometry_bias(seeds, "resolved")
    for p, q in zip(point, resolved, strict=True):
        rec.say(f"{p[0]:6.0f} | {p[8]:+7.3f} {p[9]:9.3f} {p[12]:8.2f}   | "
                f"{q[8]:+7.3f} {q[9]:9.3f} {q[12]:8.2f}  {q[11]:5d}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=120, help="realisations per stamp row")
    parser.add_argument("--seeds", type=int, default=30, help="demo seeds of part 2")
    add_output_argument(parser)
    args = parser.parse_args(argv)
    start = time.process_time()
    rec = Record()
    rec.say("Resolved star clusters: PSF photometry against the resolved fit "
            "(benchmarks/resolved_photometry.py)")
    rec.say("")
    stamp_table(rec, args.reps)
    demo_table(rec, tuple(range(args.seeds)))
    print(f"({time.process_time() - start:.0f} s of CPU)", file=sys.stderr)
    rec.write(args.output)


if __name__ == "__main__":
    main()

"""Can the pipeline tell, from the images alone, the pair whose image sits on a diffuse patch?

A measurement, not a rule: no doubt reason was built from it (see the
conclusion printed at the end of the output).

Run on demand (about 20 s of CPU per seed and scene)::

    python benchmarks/diffuse_patch_doubt.py [--seeds 12] [--output FILE]

The realistic demo scene (``render_demo(scene="realistic")``, without
sub-halo) puts a diffuse patch (``MOCK_PATCH``: a round Gaussian of 20 nJy,
sigma 0.12 arcsec) under the L1 image of one pair. For each seed the whole
pipeline runs (``analyse``, as ``finite_size_bias.py`` part 2 does); then,
per arc and band, the PSF models of every detected source (catalogue
positions and fluxes, the given PSF image) are subtracted, the residual is
smoothed by a Gaussian of ``sigma`` pixels and read at each measured image
position: the local diffuse surface brightness ``B``. Lensed light conserves
surface brightness, so ``d = B(L1) - B(L2)`` (the mean over the bands) is
the same for every pair up to light that is not lensed (intracluster light, a
member, a patch) and noise. The light that is not lensed is modelled as a
plane in the L1 position (``d = a + b x1 + c y1``); each pair's ``d`` is
compared with the plane fitted to the other pairs (not doubtful already), by
ordinary least squares or by a Huber fit with a MAD scale, as an externally
studentized residual ``t``. A pair would be doubtful where ``|t|`` exceeds the
Student-t quantile with ``n - 4`` degrees of freedom at a two-sided 1 %
Bonferroni-corrected over the ``n`` pairs (stated in advance, not tuned).

Reported per variant (smoothing, fit) and scene: in how many seeds the patch
pair would be doubtful, how many other (clean) pairs would be, the patch
pair's ``t`` and, per seed, the largest ``|t|`` of a clean pair.
"""

import argparse
import sys
import time
import warnings

import numpy as np
from _output import add_output_argument
from scipy import stats
from scipy.ndimage import gaussian_filter, shift

from lensdual.demo import compare_with_truth, render_demo, simulate_demo
from lensdual.pipeline import analyse

#: The test these records were made with: the geometric test with the linearised
#: SNR (the default until the joint test became it).
GEOMETRIC = {"test": "geometric", "snr_definition": "log"}

#: Smoothing of the PSF-subtracted residual, in pixels (the PSF FWHM is 1.3-1.7 pixels).
SMOOTHING = (1.5, 2.0)
#: The false-alarm level per seed, over all pairs (Bonferroni), two-sided.
ALPHA = 0.01
HUBER_C = 1.345


def _psf_models(shape, psf, xs, ys, fluxes):
    """The PSF image, shifted to each source and scaled by its flux, summed on a cutout."""
    out = np.zeros(shape)
    ny, nx = shape
    h = psf.shape[0] // 2
    for x, y, f in zip(xs, ys, fluxes, strict=True):
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(f)):
            continue
        ix, iy = int(np.round(x)), int(np.round(y))
        stamp = shift(psf, (y - iy, x - ix), order=3, mode="constant") * f
        y0, x0 = iy - h, ix - h
        ya, xa = max(y0, 0), max(x0, 0)
        yb, xb = min(ny, y0 + psf.shape[0]), min(nx, x0 + psf.shape[1])
        if yb > ya and xb > xa:
            out[ya:yb, xa:xb] += stamp[ya - y0:yb - y0, xa - x0:xb - x0]
    return out


def local_backgrounds(images, psf, catalogs, result, sigma):
    """Per arc (1, 2): the band-mean smoothed residual at each measured image position."""
    out = {}
    for k, arc in ((1, "L1"), (2, "L2")):
        per_band = []
        for band, img in images[arc].items():
            cat = catalogs[arc]
            xs, ys = img.wcs.world_to_pixel(cat["sky"])
            resid = np.asarray(img.data, float) - _psf_models(
                img.data.shape, psf[band], np.atleast_1d(xs), np.atleast_1d(ys),
                np.asarray(cat[f"flux_{band}"].to_value(img.unit)))
            smooth = gaussian_filter(resid, sigma, mode="nearest")
            px, py = img.wcs.world_to_pixel(result[f"sky{k}"])
            iy = np.clip(np.round(py).astype(int), 0, smooth.shape[0] - 1)
            ix = np.clip(np.round(px).astype(int), 0, smooth.shape[1] - 1)
            per_band.append(smooth[iy, ix])
        out[k] = np.mean(per_band, axis=0)
    return out


def _huber(X, d, iters=20):
    w = np.ones(len(d))
    for _ in range(iters):
        sw = np.sqrt(w)
        beta = np.linalg.lstsq(X * sw[:, None], d * sw, rcond=None)[0]
        r = d - X @ beta
        s = 1.4826 * np.median(np.abs(r - np.median(r)))
        if not s > 0:
            break
        u = np.abs(r) / (HUBER_C * s)
        w = np.where(u <= 1, 1.0, 1.0 / np.maximum(u, 1e-12))
    return beta, r, w


def studentized(d, x, y, robust):
    """Leave-one-out studentized residuals of ``d`` about a plane in (x, y), and the
    Bonferroni threshold."""
    n = len(d)
    X = np.column_stack([np.ones(n), x - x.mean(), y - y.mean()])
    p = X.shape[1]
    t = np.full(n, np.nan)
    for k in range(n):
        o = np.arange(n) != k
        if robust:
            beta, r, w = _huber(X[o], d[o])
            s2 = (1.4826 * np.median(np.abs(r - np.median(r)))) ** 2 * o.sum() / (o.sum() - p)
            Xw = X[o] * np.sqrt(w)[:, None]
        else:
            beta = np.linalg.lstsq(X[o], d[o], rcond=None)[0]
            r = d[o] - X[o] @ beta
            s2 = r @ r / (o.sum() - p)
            Xw = X[o]
        t[k] = (d[k] - X[k] @ beta) / np.sqrt(s2 * (1 + X[k] @ np.linalg.inv(Xw.T @ Xw) @ X[k]))
    return t, stats.t.ppf(1 - ALPHA / (2 * n), n - 1 - p)


def run_scene(scene, seeds):
    """Per variant: (patch seeds doubtful, seeds with a patch pair, clean doubtful, clean
    tested, patch t list, largest clean |t| per seed)."""
    tally = {}
    for seed in seeds:
        system, truth = simulate_demo(subhalo="none", seed=seed)
        demo = render_demo(system, truth, seed=seed, scene=scene)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            analysis = analyse(demo.images, psf=demo.psf, sigma_pos="auto", seed=seed,
                               null_realisations=0, **GEOMETRIC)
        res = analysis.result
        comp = compare_with_truth(res, truth, demo.centre)
        pairs = demo.mocks.pairs
        patch = np.zeros(len(res), bool)
        if "patch1" in pairs.colnames:
            under = np.asarray(pairs["patch1"], bool) | np.asarray(pairs["patch2"], bool)
            patch = np.isin(np.asarray(comp["source"]), np.asarray(pairs["source"])[under])
        ok = np.array([str(s) == "" for s in res["doubt"]])
        x, y = res["x1"].to_value("arcsec"), res["y1"].to_value("arcsec")
        for sigma in SMOOTHING:
            b = local_backgrounds(demo.images, demo.psf, analysis.catalogs, res, sigma)
            d = b[1] - b[2]
            use = ok & np.isfinite(d)
            for robust in (False, True):
                t = np.full(len(d), np.nan)
                t[use], thr = studentized(d[use], x[use], y[use], robust)
                doubtful = np.abs(t) > thr
                a = tally.setdefault((sigma, robust), [0, 0, 0, 0, [], [], thr])
                a[0] += int(np.any(doubtful & patch))
                a[1] += int(np.any(patch & use))
                a[2] += int(np.sum(doubtful & ~patch))
                a[3] += int(np.sum(use & ~patch))
                a[4] += [float(v) for v in t[patch]]
                a[5].append(float(np.nanmax(np.abs(t[~patch]))))
        print(f"{scene} seed {seed} done", file=sys.stderr, flush=True)
    return tally


def format_results(tallies, seeds):
    lines = [
        "The pair on a diffuse patch, from the images alone (benchmarks/diffuse_patch_doubt.py)",
        "",
        f"demo without sub-halo, seeds {list(seeds)}; statistic: d = B(L1) - B(L2), B the",
        "PSF-subtracted residual smoothed by a Gaussian of sigma pixels at the image, mean of",
        "the bands; t: studentized about a plane in the L1 position fitted to the other pairs;",
        f"doubtful where |t| > the Student-t quantile at a two-sided {100 * ALPHA:g} % "
        "Bonferroni-corrected over the pairs.",
        "",
        " scene      sigma  fit     threshold  patch pair doubtful  clean pairs doubtful",
    ]
    for scene, tally in tallies.items():
        for (sigma, robust), (pk, pn, ck, cn, _, _, thr) in tally.items():
            patch = f"{pk} of {pn}" if pn else "-"
            lines.append(f" {scene:10s} {sigma:5.1f}  {'huber' if robust else 'ols':6s}  "
                         f"{thr:9.2f}  {patch:19s}  {ck} of {cn}")
    lines += ["", "per seed: the patch pair's t, and the largest |t| of a clean pair"]
    for scene, tally in tallies.items():
        for (sigma, robust), (_, _, _, _, tp, tc, _) in tally.items():
            fit = "huber" if robust else "ols"
            if tp:
                lines.append(f" {scene} {sigma:.1f} {fit} patch t: "
                             + " ".join(f"{v:.1f}" for v in tp))
            lines.append(f" {scene} {sigma:.1f} {fit} max clean |t|: "
                         + " ".join(f"{v:.1f}" for v in tc))
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--scenes", nargs="+", default=["realistic", "point"],
                        choices=["realistic", "point"])
    add_output_argument(parser)
    args = parser.parse_args(argv)
    start = time.process_time()
    seeds = tuple(range(args.seeds))
    tallies = {scene: run_scene(scene, seeds) for scene in args.scenes}
    text = format_results(tallies, seeds)
    print(text)
    print(f"({time.process_time() - start:.0f} s of CPU)", file=sys.stderr)
    if args.output is not None:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(text)


if __name__ == "__main__":
    main()

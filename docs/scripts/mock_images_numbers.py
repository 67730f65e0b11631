"""Write docs/_static/scenes/numbers.inc: the numbers the mock-images page quotes.

They are read from the stored outputs the page includes or tabulates, so the
prose cannot drift from them:

- ``scenes/finite_size_bias.txt``: ``benchmarks/finite_size_bias.py`` (the
  photometry's bias on clusters of one half-light radius, and the whole
  pipeline on the point and the realistic scenes);
- ``scenes/acceptance.txt``: ``benchmarks/acceptance_pixels.py --seeds 20``
  (detection, photometry and pairing on mocks of the SMACS0723 analogue);
- ``performance/demo_time_realistic.txt``: ``benchmarks/bench_demo_time.py
  --scene realistic`` (the realistic demo's wall time);
- ``scenes/default_test.txt``, ``scenes/default_test_nosub.txt``:
  ``benchmarks/scene_default_test.py --seeds 30`` (and ``--subhalo none``)
  (the realistic scene under the default test and under the former one, and
  the diffuse-light check's doubts);
- ``scenes/diffuse_patch_doubt.txt``: ``benchmarks/diffuse_patch_doubt.py
  --seeds 12`` (the diffuse-light check against the patch's contrast);
- ``scenes/flux_pulls.txt``: ``benchmarks/scene_flux_pulls.py --seeds 30``
  (the flux-ratio pulls of the point and realistic scenes).

Run from the repository root after rerunning a benchmark::

    python benchmarks/finite_size_bias.py --pipeline-seeds 30 \
        --out docs/_static/scenes/finite_size_bias.txt
    python benchmarks/acceptance_pixels.py --seeds 20 --output docs/_static/scenes/acceptance.txt
    python benchmarks/scene_default_test.py --seeds 30 --output docs/_static/scenes/default_test.txt
    python benchmarks/scene_default_test.py --seeds 30 --subhalo none \
        --output docs/_static/scenes/default_test_nosub.txt
    python benchmarks/diffuse_patch_doubt.py --seeds 12 \
        --output docs/_static/scenes/diffuse_patch_doubt.txt
    python benchmarks/scene_flux_pulls.py --seeds 30 --output docs/_static/scenes/flux_pulls.txt
    python docs/scripts/mock_images_numbers.py
"""

import math
import re
import sys
from pathlib import Path

from scipy.stats import beta

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _records import search  # noqa: E402
from _substitutions import value_range, write  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "_static" / "scenes"

#: The half-light radii (pc) of part 1 whose flux losses and flux-ratio biases
#: the page quotes.
LOSS_RADII = (20, 40, 80)
BIAS_RADII = (40, 80)
#: The largest radius (pc) the page calls a point to the photometry.
POINT_RADIUS = 10
#: The standard error of the median of n normal draws times sqrt(n) / sigma.
MEDIAN_ERROR = math.sqrt(math.pi / 2)
#: The confidence of the upper limit on the false-flag rate when none is flagged.
CONFIDENCE = 0.95
#: The astrometric SNR bins of the acceptance run (label in its output -> short name).
ASTROMETRY_BINS = {"10-20": "10", "20-40": "20", "40-80": "40", "80-inf": "80"}


def read_bias_rows(path):
    """Part 1 of ``finite_size_bias.py``'s output: ``{r_eff [pc]: row}``, each row a
    dict of the ln flux losses on both arcs (``ln1``, ``ln2``), their closed forms
    (``pred1``, ``pred2``), the stretches and the flux ratio's bias (``ratio``) and
    its 16-84 % half-width (``ratio_width``), its closed form (``ratio_pred``) and
    the number of pairs."""
    rows = {}
    number = r"\s+([+-]?[\d.]+)"
    pattern = re.compile(r"^\s*(\d+)" + number * 10 + r"\s+(\d+)\s*$")
    for line in Path(path).read_text().splitlines():
        m = pattern.match(line)
        if m is None:
            continue
        v = [float(x) for x in m.groups()]
        rows[int(v[0])] = {"stretch1": v[2], "stretch2": v[3], "ln1": v[4], "pred1": v[5],
                           "ln2": v[6], "pred2": v[7], "ratio": v[8], "ratio_width": v[9],
                           "ratio_pred": v[10], "pairs": int(v[11])}
    if not rows:
        raise ValueError(f"{path}: no rows of part 1")
    return rows


def read_pipeline_rows(path):
    """Part 2 of ``finite_size_bias.py``'s output: ``{(scene, photometry): row}``."""
    rows = {}
    pattern = re.compile(r"^\s*(point|realistic)\s+(point|resolved)\s+(\d+) / (\d+)\s+"
                         r"(-|\d+ of \d+)\s+(\d+) of (\d+)\s+([\d.]+)\s+([\d.]+)\s*$")
    for line in Path(path).read_text().splitlines():
        m = pattern.match(line)
        if m is None:
            continue
        rows[m.group(1), m.group(2)] = {
            "false": int(m.group(3)), "tested": int(m.group(4)), "patch": m.group(5),
            "subhalo": int(m.group(6)), "seeds": int(m.group(7)),
            "size_err": float(m.group(8)), "ratio_err": float(m.group(9))}
    expected = {("point", "point"), ("realistic", "point"), ("realistic", "resolved")}
    if set(rows) != expected:
        raise ValueError(f"{path}: part 2 lacks rows {sorted(expected - set(rows))}")
    return rows


def _upper_limit(k, n):
    """The one-sided Clopper-Pearson upper limit, at CONFIDENCE, on the rate of k
    flags in n pairs."""
    return 1.0 if k == n else float(beta.ppf(CONFIDENCE, k + 1, n - k))


def _signed_pct(x):
    return f"{100 * x:+.0f}"


def finite_size_numbers(path):
    """The substitutions read from ``finite_size_bias.py``'s output."""
    bias = read_bias_rows(path)
    sub = {}
    stretches = [bias[0][k] for k in ("stretch1", "stretch2")]
    sub["mock_stretch"] = f"{min(stretches):.1f}-{max(stretches):.1f}"
    for r in LOSS_RADII:
        row = bias[r]
        # the fraction of the flux lost, 1 - F/F_true, from the median ln(F/F_true)
        sub[f"mock_loss{r}"] = value_range([100 * (1 - math.exp(row[k])) for k in ("ln1", "ln2")],
                                           "{:.0f}")
    ratios = [bias[r][f"ln{k}"] / bias[r][f"pred{k}"] for r in LOSS_RADII for k in (1, 2)]
    sub["mock_loss_over_pred"] = f"{min(ratios):.2f}-{max(ratios):.2f}"
    for r in BIAS_RADII:
        sub[f"mock_ratio_bias{r}"] = _signed_pct(math.expm1(bias[r]["ratio"]))
        sub[f"mock_ratio_pred{r}"] = _signed_pct(math.expm1(bias[r]["ratio_pred"]))
    points = [row for r, row in bias.items() if r <= POINT_RADIUS]
    sub["mock_point_max"] = f"{max(abs(row[k]) for row in points for k in ('ln1', 'ln2')):.3f}"
    # the standard error of a median, 1.2533 sigma / sqrt(n), with sigma the 16-84 %
    # half-width of the flux ratios
    noise = [MEDIAN_ERROR * row["ratio_width"] / math.sqrt(row["pairs"]) for row in points]
    sub["mock_median_noise"] = f"{min(noise):.3f}-{max(noise):.3f}"

    pipe = read_pipeline_rows(path)
    point, real = pipe["point", "point"], pipe["realistic", "point"]
    resolved = pipe["realistic", "resolved"]
    sub["mock_clean_pairs"] = str(real["tested"])
    sub["mock_false_real"] = str(real["false"])
    sub["mock_false_point"] = str(point["false"])
    sub["mock_false_limit"] = f"{100 * _upper_limit(real['false'], real['tested']):.1f}"
    sub["mock_confidence"] = f"{100 * CONFIDENCE:.0f}"
    sub["mock_subhalo_real"] = f"{real['subhalo']} of {real['seeds']}"
    sub["mock_subhalo_point"] = f"{point['subhalo']} of {point['seeds']}"
    sub["mock_patch_flagged"] = real["patch"]
    sub["mock_ratio_err_real"] = f"{100 * real['ratio_err']:.1f}"
    sub["mock_ratio_err_point"] = f"{100 * point['ratio_err']:.1f}"
    # the realistic scene again, with the resolved fit
    k, n = resolved["false"], resolved["tested"]
    sub["mock_res_pairs"] = str(n)
    sub["mock_res_false"] = str(k)
    sub["mock_res_false_limit"] = f"{100 * _upper_limit(k, n):.1f}"
    sub["mock_res_subhalo"] = f"{resolved['subhalo']} of {resolved['seeds']}"
    sub["mock_res_patch"] = resolved["patch"]
    sub["mock_res_ratio_err"] = f"{100 * resolved['ratio_err']:.1f}"
    return sub


def acceptance_numbers(path):
    """The substitutions read from ``acceptance_pixels.py``'s output."""
    lines = Path(path).read_text().splitlines()
    m = search(r"^(\d+) systems, (\d+) images$", lines, path)
    systems, images = int(m.group(1)), int(m.group(2))
    # two images (one per arc) per source
    sub = {"mock_acc_systems": str(systems), "mock_acc_sources": str(images // (2 * systems))}
    m = search(r"^image SNR \(the lower of the two bands\): median (\d+), 5-95 % (\d+-\d+)$",
               lines, path)
    sub["mock_acc_snr"] = m.group(2)
    m = search(r"^detection completeness \(SNR >= 10 in both bands\): (\d+) of (\d+) "
               r"\(([\d.]+)%\)", lines, path)
    found, n = int(m.group(1)), int(m.group(2))
    sub["mock_acc_complete"] = f"{100 * found / n:.0f} % ({found} of {n})"
    m = search(r"^spurious detections: (\d+) of (\d+)", lines, path)
    spurious, det = int(m.group(1)), int(m.group(2))
    sub["mock_acc_spurious"] = f"{100 * spurious / det:.1f} % ({spurious} of {det})"
    for label, short in ASTROMETRY_BINS.items():
        m = search(rf"astrometric rms, SNR {label}: ([\d.]+) arcsec", lines, path)
        sub[f"mock_acc_rms{short}"] = f"{m.group(1)} arcsec"
    m = search(r"^automatic pairing: (\d+) of (\d+) true pairs \(.*?\), (\d+) wrong", lines, path)
    sub["mock_acc_pairing"] = f"{m.group(1)} of {m.group(2)} correct, {m.group(3)} wrong"
    m = search(r"^flux ratio, both images SNR >= 30: median \|ln\(measured/true\)\| = "
               r"([\d.]+)%", lines, path)
    sub["mock_acc_ratio"] = f"median abs ln error {m.group(1)} %"
    return sub


def demo_time_numbers(path):
    """``bench_demo_time.py --scene realistic``: the realistic demo's warm wall time
    and the load it was measured at."""
    lines = Path(path).read_text().splitlines()
    m = search(r"summary: first (\d+) s, warm (\d+)-(\d+) s", lines, path)
    low, high = m.group(2), m.group(3)
    load = search(r"^load average at start: ([\d.]+)", lines, path).group(1)
    cores = search(r"^cores: (\d+)", lines, path).group(1)
    return {"mock_demo_warm": low if low == high else f"{low}-{high}",
            "mock_demo_cores": cores, "mock_demo_load": load}


def _interval(k, n):
    """The two-sided 95 % Clopper-Pearson interval of k in n, in per cent."""
    lower = beta.ppf(0.025, k, n - k + 1) if k else 0.0
    upper = beta.ppf(0.975, k + 1, n - k) if k < n else 1.0
    return 100 * lower, 100 * upper


def read_default_test(path):
    """``scene_default_test.py``'s totals: the default test's (clean tested, clean
    flagged, patch flagged seeds, sub-halo flagged seeds, seeds), the seeds where the
    former default differs, and the doubts (clean, patch, sub-halo, seeds)."""
    text = path.read_text()
    m = re.search(r"^default (\d+) (\d+) (\d+) (\d+) (\d+)$", text, re.MULTILINE)
    if m is None:
        raise ValueError(f"{path}: no totals row of the default test")
    totals = tuple(int(g) for g in m.groups())
    n_differ = int(search(r"seeds where the two tests differ: (\d+)",
                          text.splitlines(), path).group(1))
    doubts = re.search(r"^diffuse-light doubts: clean (\d+) patch (\d+) subhalo (\d+) "
                       r"seeds (\d+)$", text, re.MULTILINE)
    if doubts is None:
        raise ValueError(f"{path}: no totals of the diffuse-light doubts")
    return totals, n_differ, tuple(int(g) for g in doubts.groups())


def default_test_numbers(path, prefix="mock_def"):
    """``scene_default_test.py``: the realistic scene's flags under the default test,
    and the seeds where the former default differs."""
    (tested, false, patch, subhalo, seeds), n_differ, doubts = read_default_test(path)
    clean_d, patch_d, sub_d, seeds_d = doubts
    lower, upper = _interval(false, tested)
    return {f"{prefix}_clean": str(tested), f"{prefix}_false": str(false),
            f"{prefix}_rate": f"{100 * false / tested:.1f}",
            f"{prefix}_lower": f"{lower:.2f}", f"{prefix}_upper": f"{upper:.1f}",
            f"{prefix}_patch": f"{patch} of {seeds}",
            f"{prefix}_subhalo": f"{subhalo} of {seeds}",
            f"{prefix}_differ": "no seed" if n_differ == 0 else f"{n_differ} of {seeds} seeds",
            f"{prefix}_doubt_clean": str(clean_d),
            f"{prefix}_doubt_patch": f"{patch_d} of {seeds_d}",
            f"{prefix}_doubt_subhalo": f"{sub_d} of {seeds_d}"}


def default_tests_together(paths, prefix="mock_defall"):
    """The clean pairs tested and flagged over several of ``scene_default_test.py``'s
    outputs, with the two-sided 95 % interval of the rate."""
    tested = false = 0
    for path in paths:
        totals, _, _ = read_default_test(path)
        tested, false = tested + totals[0], false + totals[1]
    lower, upper = _interval(false, tested)
    return {f"{prefix}_clean": str(tested), f"{prefix}_false": str(false),
            f"{prefix}_rate": f"{100 * false / tested:.1f}",
            f"{prefix}_lower": f"{lower:.2f}", f"{prefix}_upper": f"{upper:.1f}"}


def flux_pull_numbers(path):
    """``scene_flux_pulls.py``: per scene, the median flux-ratio pull, the 16-84 %
    half-width and the per cent beyond 3; the seeds."""
    text = Path(path).read_text()
    sub = {}
    for m in re.finditer(r"^(point|realistic) (\d+) ([+-][\d.]+) ([\d.]+) ([\d.]+) ([\d.]+)$",
                         text, re.MULTILINE):
        scene, _, median, width, _, beyond = m.groups()
        sub[f"mock_pull_{scene}_median"] = median
        sub[f"mock_pull_{scene}_width"] = width
        sub[f"mock_pull_{scene}_beyond3"] = beyond
    seeds = {int(n) + 1 for n in re.findall(r"seeds 0-(\d+)$", text, re.MULTILINE)}
    if len(sub) != 6 or len(seeds) != 1:
        raise ValueError(f"{path}: expected one row per scene (point, realistic) of one run")
    sub["mock_pull_seeds"] = str(seeds.pop())
    return sub


#: The columns of a row of ``diffuse_patch_doubt.py``'s table.
PATCH_COLUMNS = ("contrast", "flux", "seeds", "doubtful", "flagged", "flagged_without", "error",
                 "t", "clean_doubtful", "clean_flagged", "clean_tested", "subhalo_flagged",
                 "subhalo_doubtful")


def read_patch_scan(path):
    """``diffuse_patch_doubt.py``'s rows: {contrast: {column: value}}."""
    rows = {}
    for line in Path(path).read_text().splitlines():
        words = line.split()
        if len(words) == len(PATCH_COLUMNS) and re.fullmatch(r"[\d.]+", words[0]):
            rows[float(words[0])] = {k: float(v) for k, v in zip(PATCH_COLUMNS, words,
                                                                   strict=True)}
    if not rows:
        raise ValueError(f"{path}: no rows of the patch scan")
    return rows


def contrast_key(contrast):
    """The substitution names' label of a contrast: 1 -> "1", 0.25 -> "0p25"."""
    return f"{contrast:g}".replace(".", "p")


def patch_scan_numbers(path):
    """Per patch contrast ``C``: the seeds where the pair's flux ratio was doubtful
    (``mock_pd_C_doubt``), where it would have been flagged without the check
    (``mock_pd_C_without``) and was flagged with it (``mock_pd_C_flagged``), its flux
    ratio's median error (``mock_pd_C_err``, %), the patch's median F150W flux
    (``mock_pd_C_flux``, nJy); over every contrast the clean pairs' doubts and the
    sub-haloed pair's."""
    rows = read_patch_scan(path)
    sub = {}
    for contrast, r in rows.items():
        key = contrast_key(contrast)
        n = int(r["seeds"])
        sub[f"mock_pd_{key}_doubt"] = f"{int(r['doubtful'])} of {n}"
        sub[f"mock_pd_{key}_without"] = f"{int(r['flagged_without'])} of {n}"
        sub[f"mock_pd_{key}_flagged"] = f"{int(r['flagged'])}"
        sub[f"mock_pd_{key}_err"] = f"{100 * r['error']:+.1f}"
        sub[f"mock_pd_{key}_flux"] = f"{r['flux']:.0f}"
    sub["mock_pd_seeds"] = str(int(max(r["seeds"] for r in rows.values())))
    sub["mock_pd_clean_doubt"] = str(int(sum(r["clean_doubtful"] for r in rows.values())))
    sub["mock_pd_clean_tested"] = str(int(sum(r["clean_tested"] for r in rows.values())))
    sub["mock_pd_subhalo_doubt"] = str(int(sum(r["subhalo_doubtful"] for r in rows.values())))
    sub["mock_pd_runs"] = str(int(sum(r["seeds"] for r in rows.values())))
    return sub


def compute(folder=OUT):
    """The substitutions (name -> text) from the stored outputs under ``folder``."""
    return (finite_size_numbers(folder / "finite_size_bias.txt")
            | acceptance_numbers(folder / "acceptance.txt")
            | demo_time_numbers(folder.parent / "performance" / "demo_time_realistic.txt")
            | default_test_numbers(folder / "default_test.txt")
            | default_test_numbers(folder / "default_test_nosub.txt", "mock_defn")
            | default_tests_together([folder / "default_test.txt",
                                      folder / "default_test_nosub.txt"])
            | patch_scan_numbers(folder / "diffuse_patch_doubt.txt")
            | flux_pull_numbers(folder / "flux_pulls.txt"))


def main(out=OUT):
    """Write the include file into ``out`` (the docs' folder by default)."""
    return write(compute(), out)


if __name__ == "__main__":
    main()

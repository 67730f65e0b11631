"""The ``lensdual`` command line: ``lensdual demo``, ``lensdual run CONFIG.toml`` and
``lensdual infer CONFIG.toml``.

``lensdual demo`` simulates the SMACS0723 analogue of the paper (two cluster
members and one sub-halo on the L2 image of one point source; see
:mod:`lensdual.demo`), renders two-band mock images and analyses them with the
real-data pipeline, knowing nothing of the truth until it compares its results
with it at the end. ``lensdual run`` runs the same pipeline on the FITS images
named in a TOML configuration file (see :mod:`lensdual.config`). ``lensdual
infer`` turns the pairs tables of such runs, each with its smooth lens, into a
posterior on the sub-halo abundance (:mod:`lensdual.inference`).

The pipeline itself, for both, is :func:`lensdual.pipeline.analyse`, which a
Python user calls directly; this module only parses the command line, reads
and writes the files and shows progress; the demo's pieces live in
:mod:`lensdual.demo`.

Exit codes: 0 success, 1 the analysis failed, 2 bad command line or
configuration (nothing is written then), 130 interrupted by Ctrl-C (nothing is
written then either).
"""

import argparse
import sys
import time
import warnings
from contextlib import contextmanager
from pathlib import Path

# The pipeline and the demo live in lensdual.pipeline and lensdual.demo.
from . import _precompile as precompile
from ._outputs import (
    ANALYSIS_OUTPUTS,
    INFERENCE_OUTPUTS,
    KNOT_OUTPUTS,
    PAIRS_TABLE_COLUMNS_DOC,
    PARAMETRIC_OUTPUTS,
    atomic_directory,
    check_output_directory,
    fit_kwargs,
    parametric_outputs,
    read_catalogs_and_pairs,
    write_analysis,
    write_knot_outputs,
    write_run_inputs,
    write_table,
)
from ._report import format_report, knot_report, parametric_paragraph
from .demo import (
    DEMO_BANDS,
    DEMO_SCENES,
    DEMO_SUBHALOES,
    compare_with_truth,
    render_demo,
    simulate_demo,
    truth_paragraph,
)
from .duality import (
    DEFAULT_SNR_DEFINITION,
    DEFAULT_TEST,
    LOG_SNR_DEFINITIONS,
    TESTS,
    resolve_snr_definition,
    resolve_test,
)
from .exceptions import PipelineError
from .photometry._psf import SOURCE_MODELS
from .pipeline import analyse, analyse_knots

__all__ = ["main", "build_parser"]

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130


# ---------------------------------------------------------------------------
# progress
# ---------------------------------------------------------------------------


class _Progress:
    """One tqdm bar over the named steps of a command (see `_show_progress`)."""

    def __init__(self, steps, args, *, desc):
        self.quiet = quiet = not _show_progress(args)
        self.bar = None
        if not quiet:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=len(steps), desc=desc, unit="step", file=sys.stderr,
                            leave=False, dynamic_ncols=True,
                            bar_format="{desc}: {n_fmt}/{total_fmt} |{bar}| {postfix} "
                                       "[{elapsed}]")

    @contextmanager
    def step(self, name):
        if self.bar is not None:
            self.bar.set_postfix_str(name)
        yield
        if self.bar is not None:
            self.bar.update(1)

    def close(self):
        if self.bar is not None:
            self.bar.close()


#: Settings of the demo's parametric fit (tests make it cheaper): the halo
#: centre is held on the cluster centre (the BCG, known to the observer).
_DEMO_FIT = {"sigma_pos": 0.01, "n_starts": 4, "fix_centre": True}


# ---------------------------------------------------------------------------
# commands
# ---------------------------------------------------------------------------


def _show_progress(args):
    """Progress bars only on a terminal (stderr) or with --progress; never with --quiet."""
    if args.quiet:
        return False
    return bool(getattr(args, "progress", False)) or sys.stderr.isatty()


def _print(args, text=""):
    if not args.quiet:
        print(text, flush=True)


#: Errors that end a command with a message and exit code 1 (ConfigError, raised
#: by load_images for a cut-out off the image, is a ValueError).
_FAILURES = (PipelineError, ValueError, OSError)


def _finish(args, command, progress, start, *, report=None, outdir=None, error=None,
            removed=()):
    """Close the progress bar; print the report (or the error); the exit code."""
    progress.close()
    if error is not None:
        kind = "" if isinstance(error, PipelineError) else f"{type(error).__name__}: "
        print(f"lensdual {command}: {kind}{error}", file=sys.stderr)
        return EXIT_FAILED
    _print(args, report)
    _print(args, f"\nOutputs in {outdir} ({time.perf_counter() - start:.1f} s).")
    if removed:
        _print(args, f"Removed {len(removed)} output(s) of an earlier lensdual run there that "
                     f"this run did not write: {', '.join(removed)}.")
    return EXIT_OK


def _cmd_demo(args):
    import astropy.units as u

    from .simulation import write_mock_images

    start = time.perf_counter()
    if args.cluster_radii[0] > args.cluster_radii[1]:
        print(f"lensdual demo: --cluster-radii: LOW must not exceed HIGH, got "
              f"{args.cluster_radii[0]:g} {args.cluster_radii[1]:g}", file=sys.stderr)
        return EXIT_USAGE
    names = ANALYSIS_OUTPUTS + ("truth_comparison.ecsv",)
    names += ("run.toml",) if args.write_config else ()
    names += PARAMETRIC_OUTPUTS if args.parametric else ()
    names += ("subhaloes.ecsv",) if args.subhalo == "cdm" else ()
    try:
        check_output_directory(args.outdir, names)
    except OSError as err:
        print(f"lensdual demo: {err}", file=sys.stderr)
        return EXIT_FAILED
    removed = []
    steps = ["simulate", "render", "detect L1", "detect L2", "pair", "photometry", "mu_size",
             "write"] + (["parametric"] if args.parametric else [])
    progress = _Progress(steps, args, desc="lensdual demo")
    if args.estimator == "adaptive":
        # the test that "auto" gives the demo's sources (no flux field below 13)
        demo_test = resolve_test(args.test, args.estimator, DEMO_BANDS,
                                 resolve_snr_definition(args.snr_definition, args.estimator),
                                 n_pairs=args.n_sources)
        precompile.start(demo_test, null_calibration=args.null_realisations > 0,
                         snr_definition=args.snr_definition)
    try:
        with progress.step("simulate the lens"):
            system, truth = simulate_demo(subhalo=args.subhalo, n_sources=args.n_sources,
                                          seed=args.seed)
        with progress.step("render mock images"):
            demo = render_demo(system, truth, seed=args.seed, scene=args.scene,
                               cluster_radii=tuple(r * u.pc for r in args.cluster_radii))
        mocks, images, centre = demo.mocks, demo.images, demo.centre
        # the null calibration is the adaptive estimator's
        null_realisations = args.null_realisations if args.estimator == "adaptive" else 0
        analysis = analyse(images, psf=demo.psf, estimator=args.estimator, sigma_pos="auto",
                           n_bootstrap=args.n_bootstrap, snr_threshold=args.snr_threshold,
                           seed=args.seed, progress=progress,
                           null_realisations=null_realisations, test=args.test,
                           snr_definition=args.snr_definition,
                           source_model=args.source_model)
        comparison = compare_with_truth(analysis.result, truth, centre)
        report = format_report(analysis, ["", truth_paragraph(comparison)])
        with atomic_directory(args.outdir, removed) as tmp:
            with progress.step("write outputs"):
                write_mock_images(mocks, tmp / "images")
                write_table(comparison, tmp / "truth_comparison.ecsv")
                if "subhaloes" in truth.meta:
                    write_table(truth.meta["subhaloes"], tmp / "subhaloes.ecsv")
                if args.write_config:
                    config, header = write_run_inputs(
                        mocks, tmp, estimator=args.estimator, test=args.test,
                        snr_definition=args.snr_definition, source_model=args.source_model,
                        n_bootstrap=args.n_bootstrap,
                        snr_threshold=args.snr_threshold, seed=args.seed, centre=centre,
                        parametric=args.parametric, null_realisations=null_realisations,
                        fit_settings=_DEMO_FIT)
                    from .config import write_config

                    write_config(tmp / "run.toml", config, header=header)
            if args.parametric:
                with progress.step("parametric fit"):
                    settings = dict(_DEMO_FIT)
                    sigma = settings.pop("sigma_pos")
                    table = parametric_outputs(analysis, tmp, fit=True, z_lens=0.39,
                                               z_source=2.2, sigma_pos=sigma, centre=centre,
                                               seed=args.seed, fit_kwargs=fit_kwargs(**settings))
                report += "\n\n" + parametric_paragraph(table)
            write_analysis(analysis, tmp, report, title="lensdual demo", images=images)
    except _FAILURES as err:
        return _finish(args, "demo", progress, start, error=err)
    return _finish(args, "demo", progress, start, report=report, outdir=args.outdir,
                   removed=removed)


def _cmd_run(args):
    from .config import ConfigError, band_oversampling, band_psfs, load_config, load_images

    start = time.perf_counter()
    try:
        config = load_config(args.config, outdir=args.outdir)
    except ConfigError as err:
        print(f"lensdual run: {err}", file=sys.stderr)
        return EXIT_USAGE
    if config.knots is not None:
        names = KNOT_OUTPUTS
    else:
        names = ANALYSIS_OUTPUTS + (PARAMETRIC_OUTPUTS if config.parametric else ())
    try:
        check_output_directory(config.outdir, names)
    except OSError as err:
        print(f"lensdual run: {err}", file=sys.stderr)
        return EXIT_FAILED
    if config.knots is not None:
        return _run_knots(args, config, start)
    removed = []
    par = config.parametric
    steps = ["read", "detect L1", "detect L2", "pair", "photometry", "mu_size", "write"]
    if par is not None:
        steps.append("parametric")
    progress = _Progress(steps, args, desc="lensdual run")
    if config.estimator == "adaptive":
        precompile.start(config.test, null_calibration=config.null_realisations > 0,
                         snr_definition=config.snr_definition)
    try:
        with progress.step("read images"), warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            images = load_images(config)
            psf = band_psfs(config)
            oversampling = band_oversampling(config)
            catalogs, manual = read_catalogs_and_pairs(config)
        analysis = analyse(images, psf=psf, estimator=config.estimator,
                           sigma_pos=config.sigma_pos, n_bootstrap=config.n_bootstrap,
                           snr_threshold=config.snr_threshold, seed=config.seed,
                           catalogs=catalogs, manual_pairs=manual, progress=progress,
                           null_realisations=config.null_realisations,
                           oversampling=oversampling, test=config.test,
                           snr_definition=config.snr_definition,
                           max_magnification=config.max_magnification,
                           source_model=config.source_model)
        read_warnings = [f"{w.category.__name__}: {w.message}" for w in caught]
        analysis.warnings[:0] = list(dict.fromkeys(read_warnings))
        for text in read_warnings:
            print(f"lensdual run: warning: {text}", file=sys.stderr)
        extra = []
        with atomic_directory(config.outdir, removed) as tmp:
            if par is not None and (par.lenstool is not None or par.fit):
                with progress.step("parametric comparison"):
                    table = parametric_outputs(
                        analysis, tmp, lenstool=par.lenstool, fit=par.fit, model=par.model,
                        z_lens=par.z_lens, z_source=par.z_source, sigma_pos=par.sigma_pos,
                        centre=par.centre, seed=config.seed,
                        fit_kwargs=fit_kwargs(par.fix_centre))
                extra = ["", parametric_paragraph(table)]
            report = format_report(analysis, extra)
            with progress.step("write outputs"):
                write_analysis(analysis, tmp, report, title=Path(args.config).stem,
                               images=images)
    except _FAILURES as err:
        return _finish(args, "run", progress, start, error=err)
    return _finish(args, "run", progress, start, report=report, outdir=config.outdir,
                   removed=removed)


@contextmanager
def _thread_pool(threads):
    """A thread pool of ``threads`` workers for the forward model, or None for one."""
    if threads <= 1:
        yield None
        return
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(threads) as pool:
        yield pool


def _cmd_infer(args):
    from ._inference_run import format_inference_report, run_inference, write_inference
    from .config import ConfigError, load_inference_config

    start = time.perf_counter()
    try:
        config = load_inference_config(args.config, outdir=args.outdir)
    except ConfigError as err:
        print(f"lensdual infer: {err}", file=sys.stderr)
        return EXIT_USAGE
    try:
        check_output_directory(config.outdir, INFERENCE_OUTPUTS)
    except OSError as err:
        print(f"lensdual infer: {err}", file=sys.stderr)
        return EXIT_FAILED
    steps = []
    for spec in config.systems:
        steps.append(f"forward model {spec.name}")
        if config.effective_weight == "composite":
            steps.append(f"composite weight {spec.name}")
        if config.calibrate:
            steps.append(f"calibration {spec.name}")
    steps += ["posterior", "write"]
    progress = _Progress(steps, args, desc="lensdual infer")
    removed = []
    try:
        with _thread_pool(args.threads) as pool:
            run = run_inference(config, client=pool, progress=progress)
        report = format_inference_report(run.posterior, title=Path(args.config).stem)
        with atomic_directory(config.outdir, removed) as tmp, progress.step("write outputs"):
            write_inference(run, tmp, report)
    except (*_FAILURES, ImportError) as err:
        return _finish(args, "infer", progress, start, error=err)
    return _finish(args, "infer", progress, start, report=report, outdir=config.outdir,
                   removed=removed)


def _analyse_knot_config(config):
    """`~lensdual.pipeline.analyse_knots` on the ``[knots]`` section of a run configuration."""
    spec = config.knots
    macro = spec.centres if spec.centres is not None else list(spec.macro_images)
    mapping = None
    if spec.mapping is not None:
        from astropy.table import Table

        mapping = Table.read(spec.mapping, format="ascii.ecsv")
    return analyse_knots(spec.catalogue, macro, knots=spec.knot_filter(), assign=spec.assign,
                         mapping=mapping, models=list(spec.models), z_source=spec.z_source,
                         sigma_pos=spec.sigma_pos, method=config.estimator,
                         snr_threshold=config.snr_threshold)


def _run_knots(args, config, start):
    """``lensdual run`` on a ``[knots]`` configuration: a catalogue, no images."""
    progress = _Progress(["analyse", "write"], args, desc="lensdual run")
    removed = []
    try:
        with progress.step("knot constellation"):
            analysis = _analyse_knot_config(config)
        report = knot_report(analysis)
        with atomic_directory(config.outdir, removed) as tmp, progress.step("write outputs"):
            write_knot_outputs(analysis, tmp, report)
    except _FAILURES as err:
        return _finish(args, "run", progress, start, error=err)
    return _finish(args, "run", progress, start, report=report, outdir=config.outdir,
                   removed=removed)


def _int_range(lo, hi=None):
    """An argparse type: an integer in [lo, hi]."""

    def convert(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < lo or (hi is not None and value > hi):
            bound = f">= {lo}" if hi is None else f"between {lo} and {hi}"
            raise argparse.ArgumentTypeError(f"expected an integer {bound}, got {value}")
        return value

    return convert


def _positive_float(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {value}")
    return value


def _config_schema():
    """The annotated example configuration of :mod:`lensdual.config`'s docstring."""
    import textwrap

    from . import config

    doc = config.__doc__
    start = doc.index("::\n\n") + 4
    end = doc.index("\n\n", doc.index("z_source", start))
    knots = doc.index("::\n\n", doc.index("[knots]")) + 4
    knots_end = doc.index("\n\n", doc.index("sigma_pos", knots))
    return (textwrap.dedent(doc[start:end]) + "\n\n# or, for a catalogue-only run (no images):\n"
            + textwrap.dedent(doc[knots:knots_end]))


def _inference_example():
    """The keys of a ``lensdual infer`` file, their meaning and defaults, for its help."""
    import textwrap

    from .config import INFERENCE_FIELDS

    lines, table = [], None
    for f in INFERENCE_FIELDS:
        if f.table != table:
            table = f.table
            lines.append("[[inference.system]] (one per constellation)"
                         if table == "inference.system" else f"[{table}]")
        kind = f"{f.type} {f.bounds()}" if f.choices is None else f.type
        text = f"{f.key} ({kind.strip()}; default {f.shown_default()}): {f.doc}"
        if f.choices is not None:
            text += f"; one of {f.bounds()}"
        lines += textwrap.wrap(text, 88, initial_indent="  ", subsequent_indent="      ")
    return "\n".join(lines) + ("\n\n[output] outdir is as for 'lensdual run' (default "
                              "lensdual-inference).")


def _add_output_options(parser):
    """--progress and --quiet, common to every command."""
    parser.add_argument("--progress", action="store_true",
                        help="show progress bars even when stderr is not a terminal (by "
                             "default they appear on a terminal only, so logs stay clean)")
    parser.add_argument("--quiet", "-q", action="store_true",
                        help="print nothing (no progress bars, no table); errors still go to "
                             "stderr")


def build_parser():
    """The argument parser of the ``lensdual`` command.

    Returns
    -------
    `argparse.ArgumentParser`
        The parser, with the ``demo``, ``run`` and ``infer`` sub-commands.
    """
    from . import __version__
    from .estimators import METHODS

    parser = argparse.ArgumentParser(
        prog="lensdual",
        description="Find dark sub-haloes with geometrical duality: compare the flux ratio "
                    "of each point-source pair of two lens arcs with its model-independent "
                    "size magnification.",
        epilog="Run 'lensdual demo' first: it needs no files and takes 11-12 s on 2 cores "
               "(about 30 s the first time).")
    parser.add_argument("--version", action="version", version=f"lensdual {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    demo = sub.add_parser(
        "demo", help="simulate the paper's SMACS0723 analogue and run the whole pipeline",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        description="Simulate the SMACS0723 analogue of the paper (main halo, two cluster "
                    "members, one sub-halo 2 mas from the L2 image of one point source), "
                    "render two-band JWST-like mock images (F150W, F200W), then detect, pair "
                    "automatically, measure by PSF photometry, estimate the size "
                    "magnification (with errors that include the estimator's own) and test "
                    "duality, without using "
                    "the truth; at the end, compare with the injected truth. Writes the "
                    "images (FITS), catalogues and the pairs table (ECSV), the pairing map "
                    "and the duality figure (PNG) and a report to OUTDIR.",
        epilog=PAIRS_TABLE_COLUMNS_DOC)
    demo.add_argument("--outdir", default="lensdual-demo", type=Path,
                      help="output directory (created if needed). lensdual replaces only "
                           "the files it wrote there itself and nobody changed since, and "
                           "removes those of its earlier outputs that this run does not "
                           "write again; the files of --write-config are never removed")
    demo.add_argument("--subhalo", choices=DEMO_SUBHALOES, default="overconcentrated",
                      help="the injected sub-halo: 1e8 Msun with c = 100 "
                           "(overconcentrated), 1e9 Msun (massive) or 1e8 Msun (small) on the "
                           "mass-concentration relation, none, or cdm: a pyHalo-convention "
                           "CDM population (1e8-1e10 Msun, pyHalo's default abundance) in a "
                           "disc around each arc, written to subhaloes.ecsv")
    demo.add_argument("--scene", choices=DEMO_SCENES, default="point",
                      help="the mock scene: every star cluster a point (point), or star "
                           "clusters of finite size (realistic), their half-light radii "
                           "drawn log-uniformly in --cluster-radii, with a clumpy host, a "
                           "cluster member, intracluster light, a diffuse patch under one "
                           "image and a JWST-like PSF with diffraction spikes (needs poppy: "
                           "pip install 'lensdual[psf]')")
    demo.add_argument("--cluster-radii", type=_positive_float, nargs=2, default=(1.0, 50.0),
                      metavar=("LOW", "HIGH"),
                      help="range of the half-light radii (pc) of --scene realistic")
    demo.add_argument("--seed", type=_int_range(0), default=0,
                      help="seed of the simulation, noise, pairing and bootstrap")
    demo.add_argument("--n-sources", type=_int_range(3, 18), default=12,
                      help="point sources in the constellation (3-18)")
    demo.add_argument("--n-bootstrap", type=_int_range(10), default=1000,
                      help="bootstrap realisations of the positional noise, for the "
                           "quad2, quad and 2v estimators (the adaptive estimator's errors "
                           "are analytic and need none)")
    demo.add_argument("--estimator", choices=sorted(METHODS), default="adaptive",
                      help="size-magnification estimator (adaptive: local fits chosen by the "
                           "data, errors that include the estimator's own; quad2, quad, 2v: "
                           "bootstrap errors of the position noise only)")
    demo.add_argument("--null-realisations", type=_int_range(0), default=1000,
                      help="simulated clean constellations for the null calibration of the "
                           "adaptive test (0: off; otherwise >= 100, and >= 370 for its "
                           "empirical p-values to confirm a flag at SNR 3)")
    demo.add_argument("--test", choices=["auto", *TESTS], default=DEFAULT_TEST,
                      help="the duality test: geometric (the flux ratio against mu_size), "
                           "joint (against mu_size and the neighbours' flux ratios, needs "
                           "13 or more sources to use them) or auto (default: joint with the "
                           "adaptive estimator and 13 or more sources, else geometric)")
    demo.add_argument("--snr-definition", choices=["auto", *LOG_SNR_DEFINITIONS],
                      default=DEFAULT_SNR_DEFINITION,
                      help="the test's SNR: log (linearised in ln mu_size), conservative "
                           "(the smaller of that and the profile-likelihood SNR: a flag needs "
                           "both; estimator adaptive) or auto (default: conservative with the "
                           "adaptive estimator, else log)")
    demo.add_argument("--source-model", choices=list(SOURCE_MODELS), default="point",
                      help="the photometry's source model: point (the PSF) or resolved "
                           "(the PSF convolved with an elliptical Gaussian of free shape, "
                           "for star clusters the PSF resolves, as in --scene realistic)")
    demo.add_argument("--snr-threshold", type=_positive_float, default=3.0,
                      help="a pair is anomalous above this duality SNR")
    demo.add_argument("--write-config", action="store_true",
                      help="also write the mock images as FITS files with error maps and "
                           "PSFs under OUTDIR/data and a matching OUTDIR/run.toml for "
                           "'lensdual run'")
    demo.add_argument("--parametric", action="store_true",
                      help="also fit a parametric lenstronomy model (NFW_ELLIPSE_CSE + SHEAR) "
                           "to the pairs and compare its magnification ratios "
                           "(parametric.ecsv, parametric.png)")
    _add_output_options(demo)
    demo.set_defaults(func=_cmd_demo)

    run = sub.add_parser(
        "run", help="run the pipeline on real images named in a TOML configuration file",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Run the pipeline on the FITS images of a TOML configuration file "
                    "(images, error or weight maps, PSFs per band and arc; optional "
                    "cut-outs, catalogues, manual pairs, parametric models). The whole "
                    "file is checked before any work starts: every problem is listed in "
                    "one message and the exit code is 2. Outputs (catalog_L1.ecsv, "
                    "catalog_L2.ecsv, pairs.ecsv, pairing_map.png, duality.png, "
                    "constellation.png, report.txt, DS9 regions) appear in the output "
                    "directory only when all of them have been written. A run replaces only "
                    "the files lensdual wrote there and nobody changed since, removes those "
                    "of its earlier outputs that it does not write again (and says which), "
                    "never touches other files, and refuses an output directory that holds "
                    "any of its inputs. "
                    "'lensdual demo --write-config' writes an example.",
        epilog=PAIRS_TABLE_COLUMNS_DOC + "\n\nThe configuration file (relative paths are "
               "relative to it; angles are strings with units):\n\n" + _config_schema())
    run.add_argument("config", type=Path, help="the TOML configuration file")
    run.add_argument("--outdir", type=Path, default=None,
                     help="output directory (overrides [output] outdir of the file)")
    _add_output_options(run)
    run.set_defaults(func=_cmd_run)

    infer = sub.add_parser(
        "infer", help="a posterior on the sub-halo abundance from analysed constellations",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Turn the pairs tables of analysed constellations (pairs.ecsv of "
                    "'lensdual run'), each with its smooth lens (a Lenstool best.par, or a "
                    "lens family for mocks), into a posterior on pyHalo's sub-halo "
                    "abundance sigma_sub: the forward model of every pair's flux anomaly "
                    "under a CDM or WDM population on a grid of abundances, the posterior "
                    "under a log-uniform prior, calibrated on mock universes of each system "
                    "(or with a composite-likelihood weight) (see the docs page 'What the "
                    "flags say about dark matter'); "
                    "with WDM and log_mhm a list of half-mode masses, the joint posterior "
                    "on sigma_sub and the half-mode mass. The "
                    "file is checked before any work starts (exit code 2 and nothing "
                    "written on a problem). Writes posterior.ecsv (the posterior, its "
                    "median and intervals in the metadata, and every system's), "
                    "posterior.png and report.txt, replacing only files that lensdual wrote "
                    "there and nobody changed since.",
        epilog="The configuration file (relative paths are relative to it):\n\n"
               + _inference_example())
    infer.add_argument("config", type=Path, help="the TOML configuration file")
    infer.add_argument("--outdir", type=Path, default=None,
                       help="output directory (overrides [output] outdir of the file; "
                            "default lensdual-inference beside the file)")
    infer.add_argument("--threads", type=_int_range(1), default=1,
                       help="threads of the forward model and the calibration's mocks (the "
                            "result does not depend on them)")
    _add_output_options(infer)
    infer.set_defaults(func=_cmd_infer)
    return parser


def main(argv=None):
    """Entry point of the ``lensdual`` command.

    Parameters
    ----------
    argv : list of str, optional
        The arguments (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        The exit code: 0 success, 1 the analysis failed, 2 bad command line or
        configuration, 130 interrupted (Ctrl-C).
    """
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, usage errors
        return int(exc.code or 0)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print(f"\nlensdual {args.command}: interrupted; the output directory was left as it "
              "was", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        precompile.cancel()  # a run that stopped before the estimator leaves none running


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

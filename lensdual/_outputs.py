"""The files of the ``lensdual`` commands: the output directory and what goes in it.

(And the few input files of a run that :mod:`lensdual.config` does not read:
detection catalogues and manual pairs.)

Every command writes into a temporary sibling of its output directory and moves
the files there only once all of them have been written
(:func:`atomic_directory`). A manifest records each file lensdual wrote there
with its SHA-256 digest, so that lensdual replaces or removes only files that it
wrote and that nobody changed since; any other file of the directory is left as
it is, and a run that would replace one stops instead.
"""

import hashlib
import json
import os
import shutil
import socket
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .exceptions import OutputConflictError

#: The file in an output directory that lists what lensdual wrote there.
MANIFEST = ".lensdual-outputs"
#: Files that ``lensdual demo --write-config`` writes for the user to run and
#: edit (a directory ends with "/"): a later command never removes them.
USER_FILES = ("run.toml", "data/")
#: The columns of ``pairs.ecsv``, for the commands' help.
PAIRS_TABLE_COLUMNS_DOC = """\
pairs.ecsv columns (one row per pair; see the "pairs table" page of the docs):
pair_id, id1, id2 (catalogue ids), x1, y1, x2, y2 (arcsec, common tangent-plane
frame, x to the west), sky1, sky2, pos_err1, pos_err2, flux1_<band>,
flux2_<band>, flux_err1_<band>, flux_err2_<band>, jacobian, parity, mu_size,
mu_size_err, mu_size_p16, mu_size_p84, mu_flux_<band>, mu_flux_err_<band>,
mu_flux, mu_flux_err, duality_ratio, duality_ratio_err, snr, snr_paper,
anomalous."""
#: The fixed names an image analysis writes at the top of its output directory.
ANALYSIS_OUTPUTS = ("pairs.ecsv", "catalog_L1.ecsv", "catalog_L2.ecsv", "pairing_map.png",
                    "duality.png", "report.txt", "pairs.reg", "sources_L1.reg",
                    "sources_L2.reg", "constellation.png")
#: The files of the parametric comparison.
PARAMETRIC_OUTPUTS = ("parametric.ecsv", "parametric.png")
#: The files of ``lensdual infer``.
INFERENCE_OUTPUTS = ("posterior.ecsv", "posterior.png", "report.txt")
#: The fixed names of a catalogue-only (knots) run.
KNOT_OUTPUTS = ("knot_images.ecsv", "report.txt")
#: A temporary directory whose process is gone is removed after this long when
#: its name does not say which process made it.
_ORPHAN_AGE_S = 3600.0


def _digest(path):
    """The SHA-256 digest of a file's contents (hex)."""
    sha = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            sha.update(block)
    return sha.hexdigest()


def _is_user_file(name):
    return any(name == f or (f.endswith("/") and name.startswith(f)) for f in USER_FILES)


def read_manifest(outdir):
    """``{relative name: SHA-256 or None}`` of what lensdual wrote into ``outdir``.

    None stands for a file listed by an older manifest without digests. A
    missing or unreadable manifest gives an empty dict: then nothing in
    ``outdir`` counts as lensdual's.
    """
    manifest = Path(outdir) / MANIFEST
    if not manifest.is_file():
        return {}
    try:
        text = manifest.read_text()
    except (OSError, UnicodeDecodeError):
        return {}
    try:
        data = json.loads(text)
    except json.JSONDecodeError:
        names = [line.strip() for line in text.splitlines() if line.strip()]
        return {n: None for n in names if ".." not in Path(n).parts}
    files = data.get("files", {}) if isinstance(data, dict) else {}
    return {n: (d if isinstance(d, str) else None) for n, d in files.items()
            if isinstance(n, str) and ".." not in Path(n).parts}


def _unchanged(outdir, name, digest):
    """Whether ``outdir/name`` is a file lensdual wrote and nobody changed since."""
    path = outdir / name
    if not path.is_file():
        return False
    return digest is None or _digest(path) == digest


def earlier_outputs(outdir, manifest=None, skip=()):
    """Files of ``outdir`` that an earlier lensdual run wrote and nobody changed since.

    The files written for the user (`USER_FILES`) are not among them, nor
    the files of an older manifest without digests, nor those in ``skip``
    (not read). ``manifest`` is that of :func:`read_manifest` when at hand.
    """
    outdir = Path(outdir)
    manifest = read_manifest(outdir) if manifest is None else manifest
    return [n for n, d in manifest.items() if d is not None and n not in skip
            and not _is_user_file(n) and _unchanged(outdir, n, d)]


def conflicting_files(outdir, names, manifest=None):
    """The files among ``names`` in ``outdir`` that a command may not replace.

    A file may be replaced only when lensdual wrote it there and it is
    unchanged since (the manifest says so). ``manifest`` is that of
    :func:`read_manifest` when at hand.
    """
    outdir = Path(outdir)
    if not outdir.is_dir():
        return []
    manifest = read_manifest(outdir) if manifest is None else manifest
    conflicts = []
    for name in names:
        path = outdir / name
        if not (path.exists() or path.is_symlink()):
            continue
        if path.is_symlink() or not path.is_file() or name not in manifest \
                or not _unchanged(outdir, name, manifest[name]):
            conflicts.append(name)
    return conflicts


def _conflict_message(outdir, names):
    listed = ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")
    return (f"the output directory {outdir} already holds {listed}, which lensdual did not "
            "write there or which changed since; lensdual never replaces such files. Move "
            "them away or choose another output directory (nothing was written)")


def check_output_directory(outdir, names=()):
    """Fail early, before any analysis, when ``outdir`` cannot be written.

    Parameters
    ----------
    outdir : path-like
        The output directory.
    names : sequence of str
        Names the command will write there: none of them may be a file that
        lensdual did not write (see `conflicting_files`).

    Raises
    ------
    OSError
        ``outdir`` (or a parent) is not a directory, cannot be created, or
        is not writable; the message names the path.
    OutputConflictError
        A file of ``names`` in ``outdir`` is not lensdual's to replace.
    """
    outdir = Path(outdir)
    if outdir.exists() and not outdir.is_dir():
        raise NotADirectoryError(f"output directory {outdir} exists and is not a directory")
    parent = outdir.resolve().parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        probe = Path(tempfile.mkdtemp(prefix=f".{outdir.resolve().name}.probe-", dir=parent))
        probe.rmdir()
    except OSError as err:
        raise OSError(f"cannot write the output directory {outdir}: {err.strerror or err} "
                      f"(in {parent}); choose another --outdir") from None
    if outdir.exists() and not os.access(outdir, os.W_OK | os.X_OK):
        raise PermissionError(f"output directory {outdir} is not writable; choose another "
                              "--outdir")
    conflicts = conflicting_files(outdir, names)
    if conflicts:
        raise OutputConflictError(_conflict_message(outdir, conflicts))


def _partial_prefix(outdir):
    return f".{outdir.name}.partial-"


def _process_alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_orphaned_partials(outdir):
    """Remove the temporary directories of killed commands beside ``outdir``.

    A command's temporary directory is named after its host and process; one
    whose process no longer runs on this host is removed, and so is one of an
    unknown process that has not changed for an hour. The directories of
    commands still running are kept.

    Returns
    -------
    list of `~pathlib.Path`
        The directories removed.
    """
    outdir = Path(outdir).resolve()
    prefix = _partial_prefix(outdir)
    host = socket.gethostname()
    removed = []
    if not outdir.parent.is_dir():
        return removed
    for path in outdir.parent.glob(prefix + "*"):
        if not path.is_dir() or path.is_symlink():
            continue
        parts = path.name[len(prefix):].split("~")
        if len(parts) == 3 and parts[1].isdigit():
            if parts[0] != host or _process_alive(int(parts[1])):
                continue
        elif time.time() - path.stat().st_mtime < _ORPHAN_AGE_S:
            continue
        shutil.rmtree(path, ignore_errors=True)
        removed.append(path)
    return removed


def _remove_stale(outdir, stale):
    """Remove the files ``stale`` of ``outdir``, then their directories left empty."""
    for name in stale:
        (outdir / name).unlink(missing_ok=True)
        parent = (outdir / name).parent
        while parent != outdir and parent.is_dir() and not any(parent.iterdir()):
            parent.rmdir()
            parent = parent.parent


def _write_manifest(outdir, written, before):
    """The manifest of ``outdir``: this run's files and the user files kept from ``before``."""
    files = {n: d for n, d in before.items()
             if _is_user_file(n) and n not in written and _unchanged(outdir, n, d)}
    files.update({n: _digest(outdir / n) for n in written})
    text = json.dumps({"lensdual_manifest": 2, "files": dict(sorted(files.items()))}, indent=1)
    (outdir / MANIFEST).write_text(text + "\n")


@contextmanager
def atomic_directory(outdir, removed=None):
    """Write into a temporary sibling of ``outdir``; move the files there on success.

    Nothing is left in ``outdir`` when the block raises: files already there
    are only replaced once every output has been written, and only when
    lensdual wrote them and nobody changed them since; any other file of the
    same name stops the command with `OutputConflictError` before anything
    is moved. Then lensdual's unchanged outputs of an earlier run that this
    run did not write again are removed (their names are appended to
    ``removed``), so that no stale file sits next to new ones; the files
    written for the user (`USER_FILES`) and all other files are never
    touched. Temporary directories of killed commands are removed first
    (`remove_orphaned_partials`).
    """
    outdir = Path(outdir).resolve()
    parent = outdir.parent
    parent.mkdir(parents=True, exist_ok=True)
    remove_orphaned_partials(outdir)
    tmp = Path(tempfile.mkdtemp(
        prefix=f"{_partial_prefix(outdir)}{socket.gethostname()}~{os.getpid()}~", dir=parent))
    try:
        yield tmp
        written = sorted(str(p.relative_to(tmp)) for p in tmp.rglob("*") if p.is_file())
        before = read_manifest(outdir)
        conflicts = conflicting_files(outdir, written, before)
        if conflicts:
            raise OutputConflictError(_conflict_message(outdir, conflicts))
        outdir.mkdir(parents=True, exist_ok=True)
        stale = earlier_outputs(outdir, before, skip=set(written))
        for path in sorted(tmp.rglob("*")):
            target = outdir / path.relative_to(tmp)
            if path.is_dir():
                target.mkdir(parents=True, exist_ok=True)
            else:
                os.replace(path, target)
        _write_manifest(outdir, written, before)
        _remove_stale(outdir, stale)
        if removed is not None:
            removed.extend(stale)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def write_table(table, path):
    """Write ``table`` as ECSV to ``path`` (replacing it)."""
    table.write(path, format="ascii.ecsv", overwrite=True)


def save_figure(fig, path, dpi):
    """Write ``fig`` to ``path`` and close it."""
    import matplotlib.pyplot as plt

    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def write_figures(analysis, directory, *, title, images=None):
    """The pairing map, the duality figure and (with ``images``) the pairs on both arcs."""
    from .visualization._run import constellation_figure, duality_figure, pairing_map_figure

    save_figure(pairing_map_figure(analysis, title), directory / "pairing_map.png", 120)
    if images is not None:
        save_figure(constellation_figure(analysis, images, title),
                     directory / "constellation.png", 110)
    save_figure(duality_figure(analysis, title), directory / "duality.png", 120)


def write_regions(analysis, directory):
    """DS9 region files: the pairs (numbered, with lines) and each arc's detections."""
    from .visualization import ds9_regions

    regions = ds9_regions(analysis.result, analysis.catalogs)
    regions["pairs"].write(str(directory / "pairs.reg"), format="ds9", overwrite=True)
    for arc in ("L1", "L2"):
        if arc in regions:
            regions[arc].write(str(directory / f"sources_{arc}.reg"), format="ds9",
                               overwrite=True)


def write_analysis(analysis, directory, report_text, *, title, images=None):
    """Catalogues, pairs table, DS9 regions, figures and report of an analysis."""
    for arc, cat in analysis.catalogs.items():
        write_table(cat, directory / f"catalog_{arc}.ecsv")
    write_table(analysis.result, directory / "pairs.ecsv")
    write_regions(analysis, directory)
    write_figures(analysis, directory, title=title, images=images)
    (directory / "report.txt").write_text(report_text + "\n")


def read_catalog(path):
    """A detection catalogue (ECSV) of a run configuration, with a ``sky`` column."""
    import astropy.units as u
    from astropy.coordinates import SkyCoord
    from astropy.table import QTable

    cat = QTable.read(path, format="ascii.ecsv")
    if "sky" not in cat.colnames:
        cat["sky"] = SkyCoord(u.Quantity(cat["ra"], u.deg), u.Quantity(cat["dec"], u.deg))
    return cat


def read_catalogs_and_pairs(config):
    """The catalogues (``{arc: QTable}`` or None) and manual pairs (or None) of a run."""
    from astropy.table import QTable

    catalogs = None
    if config.catalogs is not None:
        catalogs = {arc: read_catalog(path) for arc, path in config.catalogs.items()}
    manual = None
    if config.pairing_method == "manual":
        manual = QTable.read(config.pairs_file, format="ascii.ecsv")
    return catalogs, manual


def fit_kwargs(fix_centre=False, n_starts=None, max_nfev=None):
    """Keyword arguments of the parametric fit for :func:`parametric_outputs`."""
    kwargs = {}
    if fix_centre:
        kwargs["fixed_params"] = {0: {"center_x": 0.0, "center_y": 0.0}}
    if n_starts is not None:
        kwargs["n_starts"] = n_starts
    if max_nfev is not None:
        kwargs["max_nfev"] = max_nfev
    return kwargs


def parametric_outputs(analysis, directory, *, lenstool=None, fit=False, model=None,
                       z_lens=None, z_source=None, sigma_pos=0.01, centre=None, seed=0,
                       fit_kwargs=None):
    """The parametric comparison: table and figure into ``directory``."""
    import astropy.units as u

    from .parametric import parametric_comparison

    kwargs = {"lenstool": lenstool, "fit": fit, "z_lens": z_lens, "z_source": z_source,
              "seed": seed, "centre": centre,
              "fit_kwargs": {"sigma_pos": u.Quantity(sigma_pos, u.arcsec),
                             **(fit_kwargs or {})}}
    if model is not None:
        kwargs["model"] = tuple(model)
    table, fig = parametric_comparison(analysis.result, **kwargs)
    write_table(table, directory / "parametric.ecsv")
    save_figure(fig, directory / "parametric.png", 120)
    return table


def write_run_inputs(mocks, directory, *, estimator, n_bootstrap, snr_threshold, seed,
                     centre, parametric=False, null_realisations=0, fit_settings=None,
                     test="auto", snr_definition="auto", source_model="point"):
    """FITS images, error maps and PSFs of the mocks, and a config that reads them.

    ``snr_definition`` and ``source_model`` are written only where they differ
    from the config's defaults.

    ``fit_settings`` (with ``sigma_pos`` and ``fix_centre``) are the demo's
    parametric-fit settings written to ``[parametric]`` when ``parametric``.
    """
    from astropy.io import fits

    from .config._schema import default

    data = directory / "data"
    data.mkdir(parents=True, exist_ok=True)
    config = {
        "output": {"outdir": "run-output"},
        "analysis": {"estimator": estimator, "sigma_pos": "auto",
                     "n_bootstrap": int(n_bootstrap), "test": test,
                     **({"snr_definition": snr_definition}
                        if snr_definition != default("analysis", "snr_definition") else {}),
                     **({"source_model": source_model}
                        if source_model != default("analysis", "source_model") else {}),
                     "snr_threshold": float(snr_threshold),
                     "seed": int(seed), "null_realisations": int(null_realisations)},
        "bands": {}, "arcs": {"L1": {}, "L2": {}},
    }
    for (arc, band), image in mocks.items():
        header = image.wcs.to_header()
        header["BUNIT"] = image.unit.to_string()
        header["BAND"] = band
        fits.writeto(data / f"{arc}_{band}_sci.fits", np.asarray(image.data, dtype=float),
                     header, overwrite=True)
        fits.writeto(data / f"{arc}_{band}_err.fits",
                     np.asarray(image.uncertainty.array, dtype=float), header, overwrite=True)
        config["arcs"][arc][band] = {"image": f"data/{arc}_{band}_sci.fits",
                                     "error": f"data/{arc}_{band}_err.fits"}
        if band not in config["bands"]:
            fits.writeto(data / f"psf_{band}.fits", np.asarray(image.psf, dtype=float),
                         overwrite=True)
            config["bands"][band] = {"psf": f"data/psf_{band}.fits"}
    if parametric:
        config["parametric"] = {"fit": True, "z_lens": 0.39, "z_source": 2.2,
                                "sigma_pos": f"{fit_settings['sigma_pos']} arcsec",
                                "centre": f"{centre.ra.deg:.7f} {centre.dec.deg:.7f}",
                                "fix_centre": bool(fit_settings.get("fix_centre", False))}
    header = ("lensdual run configuration written by `lensdual demo --write-config`:\n"
              "the demo's mock images as FITS files (science, error map, PSF),\n"
              "analysed with the demo's settings. Run it with\n"
              "    lensdual run run.toml\n"
              "Relative paths are relative to this file.")
    return config, header


def write_knot_figure(table, path):
    """``mu_size`` against the models' ratios of one knot table, as a PNG."""
    from .visualization._run import knot_figure

    save_figure(knot_figure(table), path, 120)



def write_knot_outputs(analysis, directory, report_text):
    """The outputs of a knots run: the images table, one table (and figure) per macro pair."""
    write_table(analysis.knot_pairs.images, directory / "knot_images.ecsv")
    for (m1, m2), table in analysis.tables.items():
        stem = f"knots_{m1}_{m2}"
        write_table(table, directory / f"{stem}.ecsv")
        if table.meta.get("models"):
            write_knot_figure(table, directory / f"{stem}.png")
    (directory / "report.txt").write_text(report_text + "\n")

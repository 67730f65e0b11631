"""Nothing of the user's is lost: what a command may write, replace and remove.

A run never replaces or removes a file it reads, nor a file that lensdual did not
write (or that changed since it did); an interrupted run leaves nothing behind that a
later run does not clean up. The manifest is checked against digests computed here
with hashlib, not with lensdual's own helper.
"""

import hashlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import textwrap

import pytest
from _demo_config import FAST, absolute_config, write

from lensdual import _outputs
from lensdual._outputs import MANIFEST, OutputConflictError, atomic_directory
from lensdual.cli import main


def sha256(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def snapshot(directory):
    """{relative path: digest} of every file under ``directory``."""
    return {str(p.relative_to(directory)): sha256(p)
            for p in sorted(directory.rglob("*")) if p.is_file()}


def write_manifest(outdir, names):
    """A manifest that says lensdual wrote ``names`` (digests of the files as they are)."""
    files = {n: sha256(outdir / n) for n in names}
    (outdir / MANIFEST).write_text(json.dumps({"lensdual_manifest": 2, "files": files}))


def no_partials(directory):
    return not [p for p in directory.iterdir() if ".partial-" in p.name]


@pytest.fixture
def demo_copy(demo_dir, tmp_path):
    """A copy of the demo's run inputs (run.toml, data/) that a test may break."""
    copy = tmp_path / "copy"
    shutil.copytree(demo_dir / "data", copy / "data")
    shutil.copy(demo_dir / "run.toml", copy / "run.toml")
    return copy


@pytest.fixture
def no_analysis(monkeypatch):
    """Make the analysis fail loudly: these runs must stop before it."""
    import lensdual.cli as cli

    def never(*args, **kwargs):
        raise AssertionError("the analysis ran")

    monkeypatch.setattr(cli, "analyse", never)


# --- a run never touches its own inputs -----------------------------------


def test_the_demo_directory_as_the_output_of_its_own_run_is_refused(demo_dir, tmp_path, capsys,
                                                                     no_analysis):
    """``lensdual run lensdual-demo/run.toml --outdir lensdual-demo``: exit 2, nothing lost."""
    out = tmp_path / "demo"
    shutil.copytree(demo_dir, out)
    before = snapshot(out)
    assert main(["run", str(out / "run.toml"), "--outdir", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "outdir (argument)" in err and "run.toml" in err and "data/" in err
    assert "never replaces or removes its own inputs" in err
    assert snapshot(out) == before
    assert no_partials(tmp_path)


def test_an_output_directory_next_to_the_config_is_refused(demo_copy, capsys, monkeypatch,
                                                           no_analysis):
    """``--outdir .`` beside run.toml, and ``[output] outdir = "."`` in the file."""
    before = snapshot(demo_copy)
    monkeypatch.chdir(demo_copy)
    assert main(["run", "run.toml", "--outdir", ".", "--quiet"]) == 2
    assert "holds run.toml" in capsys.readouterr().err
    cfg = (demo_copy / "run.toml").read_text().replace('outdir = "run-output"', 'outdir = "."')
    assert 'outdir = "."' in cfg
    (demo_copy / "run.toml").write_text(cfg)
    before["run.toml"] = sha256(demo_copy / "run.toml")
    assert main(["run", "run.toml", "--quiet"]) == 2
    assert "[output] outdir" in capsys.readouterr().err
    assert snapshot(demo_copy) == before


def test_a_manual_pairs_file_in_the_output_directory_is_refused(demo_dir, tmp_path, capsys,
                                                               no_analysis):
    from astropy.table import QTable

    out = tmp_path / "out"
    out.mkdir()
    pairs = QTable.read(demo_dir / "pairs.ecsv", format="ascii.ecsv")
    QTable({"id1": pairs["id1"], "id2": pairs["id2"]}).write(out / "pairs.ecsv",
                                                             format="ascii.ecsv")
    digest = sha256(out / "pairs.ecsv")
    cfg = absolute_config(demo_dir)
    cfg["pairing"] = {"method": "manual", "file": str(out / "pairs.ecsv")}
    assert main(["run", str(write(tmp_path / "c.toml", cfg)), "--outdir", str(out)]) == 2
    assert "holds pairs.ecsv" in capsys.readouterr().err
    assert sha256(out / "pairs.ecsv") == digest


def test_input_files_lists_every_file_a_run_reads(demo_copy):
    from lensdual.config import load_config

    config = load_config(demo_copy / "run.toml")
    files = config.input_files()
    assert files[0] == (demo_copy / "run.toml").resolve()
    expected = {p.resolve() for p in (demo_copy / "data").iterdir()}
    assert set(files[1:]) == expected
    assert len(files) == len(set(files))


# --- a file lensdual did not write is never replaced ----------------------


def test_a_user_file_with_an_output_name_stops_the_run_before_the_analysis(
        demo_dir, tmp_path, capsys, no_analysis):
    out = tmp_path / "out"
    out.mkdir()
    (out / "report.txt").write_text("my notes on this cluster\n")
    cfg = write(tmp_path / "c.toml", absolute_config(demo_dir))
    assert main(["run", str(cfg), "--outdir", str(out), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "report.txt" in err and "never replaces such files" in err
    assert "nothing was written" in err
    assert (out / "report.txt").read_text() == "my notes on this cluster\n"
    assert no_partials(tmp_path)


def test_an_output_changed_since_lensdual_wrote_it_is_not_replaced(tmp_path):
    out = tmp_path / "out"
    with atomic_directory(out) as tmp:
        (tmp / "pairs.ecsv").write_text("first\n")
    (out / "pairs.ecsv").write_text("edited by hand\n")
    with pytest.raises(OutputConflictError, match="pairs.ecsv"):
        with atomic_directory(out) as tmp:
            (tmp / "pairs.ecsv").write_text("second\n")
            (tmp / "report.txt").write_text("second\n")
    assert (out / "pairs.ecsv").read_text() == "edited by hand\n"
    assert not (out / "report.txt").exists()
    assert no_partials(tmp_path)


def test_an_unchanged_output_is_replaced_and_the_manifest_holds_digests(tmp_path):
    out = tmp_path / "out"
    with atomic_directory(out) as tmp:
        (tmp / "pairs.ecsv").write_text("first\n")
    with atomic_directory(out) as tmp:
        (tmp / "pairs.ecsv").write_text("second\n")
        (tmp / "images").mkdir()
        (tmp / "images" / "L1.fits").write_bytes(b"\x00\x01")
    assert (out / "pairs.ecsv").read_text() == "second\n"
    manifest = json.loads((out / MANIFEST).read_text())["files"]
    assert manifest == {"images/L1.fits": sha256(out / "images" / "L1.fits"),
                        "pairs.ecsv": sha256(out / "pairs.ecsv")}


# --- stale outputs: only lensdual's own, unchanged ones ------------------


def test_stale_outputs_are_removed_and_other_files_kept(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "images").mkdir()
    for name in ("parametric.ecsv", "parametric.png", "notes.txt", "report.txt",
                 "images/L1.fits"):
        (out / name).write_text("old " + name)
    write_manifest(out, ["parametric.ecsv", "parametric.png", "report.txt", "images/L1.fits"])
    (out / "parametric.png").write_text("changed by the user")
    removed = []
    with atomic_directory(out, removed) as tmp:
        (tmp / "report.txt").write_text("new")
    assert sorted(removed) == ["images/L1.fits", "parametric.ecsv"]
    assert not (out / "parametric.ecsv").exists() and not (out / "images").exists()
    assert (out / "parametric.png").read_text() == "changed by the user"
    assert (out / "notes.txt").read_text() == "old notes.txt"
    assert (out / "report.txt").read_text() == "new"


def test_files_named_like_outputs_without_a_manifest_are_kept(demo_dir, tmp_path, capsys):
    """No manifest: nothing there is lensdual's, whatever its name."""
    out = tmp_path / "out"
    out.mkdir()
    for name in ("parametric.ecsv", "parametric.png", "run.toml", "notes.txt"):
        (out / name).write_text("old")
    assert main(["run", str(write(tmp_path / "c.toml", absolute_config(demo_dir))),
                 "--outdir", str(out)]) == 0
    assert "Removed" not in capsys.readouterr().out
    for name in ("parametric.ecsv", "parametric.png", "run.toml", "notes.txt"):
        assert (out / name).read_text() == "old", name
    manifest = json.loads((out / MANIFEST).read_text())["files"]
    assert {"pairs.ecsv", "pairs.reg", "sources_L1.reg", "report.txt"} <= set(manifest)
    assert "notes.txt" not in manifest and "run.toml" not in manifest


def test_the_files_written_for_the_user_are_never_removed(tmp_path):
    """run.toml and data/ of ``--write-config`` survive a later run that does not write them."""
    out = tmp_path / "out"
    with atomic_directory(out) as tmp:
        (tmp / "data").mkdir()
        (tmp / "data" / "L1_sci.fits").write_bytes(b"image")
        (tmp / "run.toml").write_text("[analysis]\n")
        (tmp / "pairs.ecsv").write_text("first\n")
    removed = []
    with atomic_directory(out, removed) as tmp:
        (tmp / "pairs.ecsv").write_text("second\n")
    assert removed == []
    assert (out / "data" / "L1_sci.fits").read_bytes() == b"image"
    assert (out / "run.toml").read_text() == "[analysis]\n"
    # still lensdual's: a third run may replace them while they are unchanged
    with atomic_directory(out) as tmp:
        (tmp / "run.toml").write_text("[analysis]\nseed = 1\n")
    assert (out / "run.toml").read_text() == "[analysis]\nseed = 1\n"


def test_rerunning_the_demo_keeps_a_hand_edited_config_and_its_data(demo_dir, tmp_path,
                                                                    capsys):
    out = tmp_path / "demo"
    shutil.copytree(demo_dir, out)
    edited = (out / "run.toml").read_text().replace("seed = 5", "seed = 6")
    assert edited != (out / "run.toml").read_text()
    (out / "run.toml").write_text(edited)
    data = snapshot(out / "data")
    # with --write-config the demo would replace the edited file: it stops before any work
    assert main(["demo", "--outdir", str(out), "--write-config", "--quiet", *FAST]) == 1
    assert "run.toml" in capsys.readouterr().err
    assert main(["demo", "--outdir", str(out), "--quiet", *FAST]) == 0
    assert (out / "run.toml").read_text() == edited
    assert snapshot(out / "data") == data
    assert (out / "pairs.ecsv").is_file()


# --- interrupted runs -------------------------------------------------------


def test_a_killed_run_leaves_a_folder_the_next_run_removes(tmp_path):
    out = tmp_path / "out"
    script = textwrap.dedent(f"""
        import os, signal
        from pathlib import Path
        from lensdual._outputs import atomic_directory
        with atomic_directory(Path({str(out)!r})) as tmp:
            (tmp / "pairs.ecsv").write_text("half")
            os.kill(os.getpid(), signal.SIGKILL)
    """)
    done = subprocess.run([sys.executable, "-c", script], timeout=120)
    assert done.returncode == -signal.SIGKILL
    left = [p for p in tmp_path.iterdir() if ".partial-" in p.name]
    assert len(left) == 1 and (left[0] / "pairs.ecsv").is_file()
    assert not out.exists()
    # a running command's folder (this process) is kept
    alive = tmp_path / f".out.partial-{socket.gethostname()}~{os.getpid()}~abc"
    alive.mkdir()
    with atomic_directory(out) as tmp:
        (tmp / "report.txt").write_text("done")
    assert not left[0].exists()
    assert alive.is_dir()
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "report.txt"]


def test_an_old_nameless_partial_folder_is_removed_after_an_hour(tmp_path):
    out = tmp_path / "out"
    old = tmp_path / ".out.partial-x1y2z3"
    new = tmp_path / ".out.partial-a1b2c3"
    old.mkdir()
    new.mkdir()
    hours_ago = os.path.getmtime(old) - 2 * 3600
    os.utime(old, (hours_ago, hours_ago))
    assert _outputs.remove_orphaned_partials(out) == [old]
    assert new.is_dir()


def test_ctrl_c_prints_one_line_and_writes_nothing(demo_dir, tmp_path, capsys, monkeypatch):
    import lensdual.cli as cli

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "analyse", interrupted)
    out = tmp_path / "out"
    cfg = write(tmp_path / "c.toml", absolute_config(demo_dir))
    assert main(["run", str(cfg), "--outdir", str(out), "--quiet"]) == 130
    err = capsys.readouterr().err
    assert err.strip() == ("lensdual run: interrupted; the output directory was left as it "
                           "was")
    assert "Traceback" not in err
    assert not out.exists() and no_partials(tmp_path)


# --- what the help says ----------------------------------------------------


def test_the_help_names_the_files_and_what_a_run_replaces(capsys):
    assert main(["run", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "catalog_L1.ecsv" in text and "catalogue_L1" not in text
    assert "removes those of its earlier outputs" in text
    assert "refuses an output directory that holds any of its inputs" in text
    assert main(["demo", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "magnification with bootstrap errors" not in text
    assert "adaptive estimator's errors are analytic" in text

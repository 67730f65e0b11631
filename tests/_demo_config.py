"""The demo's outputs and run configuration for the tests that run ``lensdual run`` on
them or on a broken copy of them."""

import tomllib

#: Settings of the small demo most command tests share (10 sources, 100 bootstraps,
#: no null calibration).
FAST = ["--n-sources", "10", "--n-bootstrap", "100", "--seed", "5", "--null-realisations", "0"]


def run_demo(tmp_path_factory, name, args=FAST):
    """Run ``lensdual demo --write-config`` with ``args`` into a new folder; its path."""
    from lensdual.cli import main

    out = tmp_path_factory.mktemp(name) / "demo"
    assert main(["demo", "--outdir", str(out), "--write-config", "--quiet", *args]) == 0
    return out


def absolute_config(demo_dir):
    """``demo_dir/run.toml`` (written by ``lensdual demo --write-config``) as a dict
    whose image, error-map and PSF paths are absolute."""
    cfg = tomllib.loads((demo_dir / "run.toml").read_text())
    for arc in ("L1", "L2"):
        for spec in cfg["arcs"][arc].values():
            for key in ("image", "error"):
                if key in spec:
                    spec[key] = str(demo_dir / spec[key])
    for spec in cfg["bands"].values():
        spec["psf"] = str(demo_dir / spec["psf"])
    return cfg


def write(path, cfg):
    """Write ``cfg`` as TOML to ``path``; returns ``path``."""
    from lensdual.config import format_config

    path.write_text(format_config(cfg))
    return path

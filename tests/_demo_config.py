"""The demo's run configuration with absolute paths, for tests that break a copy of it
(test_cli, test_hostile)."""

import tomllib


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

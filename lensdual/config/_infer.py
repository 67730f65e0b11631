"""Loading and validating a ``lensdual infer`` configuration: :func:`load_inference_config`
and the specification classes it returns.

The keys, their defaults and bounds come from the schema
(`._schema.INFERENCE_FIELDS`); the validator reuses the typed getters of
``lensdual run``'s (`._core._Validator`) and keeps here the rules that join
several keys and the checks of the files: each pairs table is read and must
be a duality result with tested pairs, each Lenstool file is read.
"""

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from astropy import units as u

from ..exceptions import ConfigError
from . import _schema
from ._core import _ABSENT, _BAD, _valid, _Validator, read_toml
from ._values import _describe, _suggest
from ._writer import _toml_key

__all__ = ["InferenceSystemSpec", "InferenceConfig", "load_inference_config"]

_SYSTEM = _schema.INFERENCE_SYSTEM
_KEYS = {t: tuple(f.key for f in _schema.INFERENCE_FIELDS if f.table == t)
         for t in ("inference", _SYSTEM)}
_KEYS["output"] = _schema.keys("output")


def _d(key):
    return _schema.inference_field("inference", key).default


@dataclass(frozen=True)
class InferenceSystemSpec:
    """One constellation of a ``lensdual infer`` run (a table of ``[[inference.system]]``).

    Every parameter is also an attribute of the same name.

    Parameters
    ----------
    name : str
        The system's name (default: the pairs file's name without its suffix).
    pairs : `~pathlib.Path`
        The ECSV duality result (``pairs.ecsv`` of ``lensdual run``).
    table : `~astropy.table.QTable`
        That table, as read.
    lenstool : `~pathlib.Path` or None
        The Lenstool parameter file of the smooth lens (or None with ``family``).
    family : str or None
        The lens family of a mock (`lensdual.simulation.FAMILIES`), or None.
    z_source : float or None
        The source redshift (with ``lenstool``; a family has its own).
    sigma_pos : `~astropy.units.Quantity` or None
        The composite weight's position error (None: the table's).
    flux_rel_err : float or None
        The composite weight's relative flux error (None: the table's).
    radius : `~astropy.units.Quantity` or None
        The disc radius of the sub-haloes (None: the default of
        `~lensdual.inference.simulate_anomalies`).
    """

    name: str
    pairs: Path
    table: object
    lenstool: Path | None = None
    family: str | None = None
    z_source: float | None = None
    sigma_pos: u.Quantity | None = None
    flux_rel_err: float | None = None
    radius: u.Quantity | None = None


@dataclass(frozen=True)
class InferenceConfig:
    """A validated configuration of ``lensdual infer``, as made by :func:`load_inference_config`.

    Every parameter is also an attribute of the same name; paths are absolute.

    Parameters
    ----------
    path : `~pathlib.Path`
        The configuration file.
    outdir : `~pathlib.Path`
        The output directory (it may not exist yet).
    systems : tuple of `InferenceSystemSpec`
        The constellations, in the order of the file.
    model : str
        ``"CDM"`` or ``"WDM"``.
    log_mhm : float, tuple of float or None
        log10 of the WDM half-mode mass (WDM only); a tuple (at least two
        distinct values, sorted) is the grid of the joint posterior on
        ``sigma_sub`` and the half-mode mass
        (:func:`~lensdual.inference.half_mode_posterior`).
    log_m_host : float
        log10 of the host halo's mass.
    sigma_sub : tuple of float
        The bounds of the abundance grid, kpc^-2.
    n_sigma_sub : int
        Abundances of the grid (log-spaced).
    n_realisations : int
        Realisations per abundance.
    seed : int
        Seed of the realisations and the mocks.
    calibrate : bool
        Whether the posterior is recalibrated on mock universes
        (:func:`~lensdual.inference.calibrate_posterior`; with a grid of
        half-mode masses, both marginals).
    n_calibration : int
        Mocks of each system's calibration.
    weight : str, float or None
        ``"composite"`` or a weight in (0, 1] for every system; None (not
        given): :attr:`effective_weight` decides.
    n_mocks : int
        Mocks of each composite weight.
    anomaly : str
        The pairs' anomalies, ``"geometric"`` or ``"joint"``
        (:func:`~lensdual.inference.pair_anomalies`); ``"auto"`` in the file
        is resolved when it is read: ``"joint"`` where every system's table is
        a joint-test table, else ``"geometric"``.
    anomaly_source : str
        ``"configured"`` (``anomaly`` given) or ``"auto"``.
    los_normalization : float
        Line-of-sight haloes (pyHalo's ``LOS_normalization``; 0: none).
    two_halo : bool
        pyHalo's two-halo term with line-of-sight haloes.
    """

    path: Path
    outdir: Path
    systems: tuple
    model: str = _d("model")
    log_mhm: float | tuple | None = _d("log_mhm")
    log_m_host: float = _d("log_m_host")
    sigma_sub: tuple = _d("sigma_sub")
    n_sigma_sub: int = _d("n_sigma_sub")
    n_realisations: int = _d("n_realisations")
    seed: int = _d("seed")
    calibrate: bool = _d("calibrate")
    n_calibration: int = _d("n_calibration")
    weight: str | float | None = _d("weight")
    n_mocks: int = _d("n_mocks")
    anomaly: str = _d("anomaly")
    los_normalization: float = _d("los_normalization")
    two_halo: bool = _d("two_halo")
    anomaly_source: str = "configured"

    @property
    def half_mode(self):
        """Whether the run is the joint posterior on ``sigma_sub`` and the half-mode mass
        (``log_mhm`` is a grid)."""
        return isinstance(self.log_mhm, tuple)

    @property
    def effective_weight(self):
        """The weight every system gets: ``weight``, else 1 with the calibration and
        ``"composite"`` without it."""
        return _effective_weight({"weight": self.weight, "calibrate": self.calibrate})

    @property
    def grid(self):
        """The abundance grid, log-spaced between the bounds (kpc^-2)."""
        return np.geomspace(*self.sigma_sub, self.n_sigma_sub) / u.kpc**2

    def input_files(self):
        """Every file the run reads: the configuration, pairs tables and Lenstool files.

        Returns
        -------
        list of `~pathlib.Path`
            Absolute paths, each once, the configuration file first.
        """
        files = [self.path]
        for s in self.systems:
            files += [s.pairs, s.lenstool]
        return list(dict.fromkeys(f for f in files if f is not None))


class _InferenceValidator(_Validator):
    """Checks a parsed ``lensdual infer`` document and collects every problem."""

    def get(self, table, key, sec, where=None):
        f = _schema.inference_field(where or sec, key)
        if f.type == "string":
            return self.get_str(table, key, sec, f.default, choices=f.choices)
        if f.type == "integer":
            return self.get_int(table, key, sec, f.default, minimum=f.minimum)
        if f.type == "real":
            return self.get_real(table, key, sec, f.default, above=f.above)
        if f.type == "boolean":
            return self.get_bool(table, key, sec, f.default)
        if f.type == "angle":
            return self.get_angle(table, key, sec, f.default)
        if f.type == "file":
            return self.get_file(table, key, sec)
        raise TypeError(f"{f.name}: no generic getter for a {f.type}")

    def check_root(self):
        for key, value in self.data.items():
            if key in _schema.INFERENCE_TABLES:
                continue
            if isinstance(value, dict):
                self.add(f"[{_toml_key(key)}]: unknown table"
                         f"{_suggest(key, list(_schema.INFERENCE_TABLES), fmt='[{}]')} "
                         "(a lensdual infer configuration holds [output] and [inference])")
            else:
                owner = "inference" if key in _KEYS["inference"] else None
                where = (f" (it belongs in [{owner}])" if owner else
                         " (the top level holds only the tables [output] and [inference])")
                self.add(f"{_toml_key(key)}: unknown top-level key{where}")

    def output(self):
        table = self.section("output") or {}
        self.unknown_keys(table, _KEYS["output"], "output")
        value = self.get_str(table, "outdir", "output", default=_schema.INFERENCE_OUTDIR)
        if value is not _BAD and not value.strip():
            self.add("[output] outdir: must not be empty")
            value = _BAD
        if self.outdir_arg is not None:
            where, path = "outdir (argument)", Path(self.outdir_arg).expanduser().resolve()
        elif value is _BAD:
            return None
        else:
            where, path = "[output] outdir", self.resolve(value)
        if path.exists() and not path.is_dir():
            self.add(f"{where}: {path} exists and is not a directory")
        return path

    def inference(self):
        """The settings of ``[inference]`` (its ``system`` array apart)."""
        sec = "inference"
        table = self.section(sec)
        if table is None:
            if sec not in self.data:
                self.add("[inference]: missing: a lensdual infer configuration needs an "
                         "[inference] table and at least one [[inference.system]]")
            return None
        self.unknown_keys(table, (*_KEYS[sec], "system"), sec)
        out = {k: self.get(table, k, sec) for k in ("model", "log_m_host", "n_sigma_sub",
                                                     "n_realisations", "seed", "n_mocks",
                                                     "anomaly", "los_normalization",
                                                     "two_halo", "n_calibration")}
        if out["los_normalization"] is not _BAD and out["los_normalization"] < 0:
            self.add("[inference] los_normalization: must be >= 0 (0: no line-of-sight "
                     f"haloes, 1: pyHalo's default), got {out['los_normalization']:g}")
            out["los_normalization"] = _BAD
        out["log_mhm"] = self.log_mhm(table.get("log_mhm", _ABSENT), out["model"])
        if out["model"] == "WDM" and out["log_mhm"] is None:
            self.add('[inference] log_mhm: required with model = "WDM" (log10 of the '
                     "half-mode mass, Msun)")
        if out["model"] == "CDM" and isinstance(out["log_mhm"], float):
            self.add('[inference] log_mhm: a WDM parameter; give model = "WDM" with it')
        self.population(out)
        out["sigma_sub"] = self.bounds(table.get("sigma_sub", _ABSENT))
        out["calibrate"] = self.calibrate(table)
        out["weight"] = self.weight(table.get("weight", _ABSENT))
        n = out["n_sigma_sub"]
        if _effective_weight(out) == "composite" and n is not _BAD and n < 5:
            self.add('[inference] n_sigma_sub: weight = "composite" needs at least 5 '
                     f"abundances (the slope and curvature of the log-likelihood), got {n}")
        return out

    def log_mhm(self, value, model):
        """A number, or with WDM a list of at least two distinct numbers (the grid of the
        joint posterior with the half-mode mass), returned as a sorted tuple."""
        if not isinstance(value, list):
            return self.get_real({} if value is _ABSENT else {"log_mhm": value}, "log_mhm",
                                 "inference", _d("log_mhm"))
        where = "[inference] log_mhm"
        if model == "CDM":
            self.add(f'{where}: a list of half-mode masses (the joint posterior) needs '
                     'model = "WDM"')
            return _BAD
        bad = [v for v in value if isinstance(v, bool) or not isinstance(v, (int, float))
               or not math.isfinite(v)]
        if bad:
            self.add(f"{where}: expected a number or a list of finite numbers (log10 Msun), "
                     f"got a list holding {_describe(bad[0])}")
            return _BAD
        values = [float(v) for v in value]
        if len(values) < 2:
            self.add(f"{where}: a list needs at least two half-mode masses (the grid of the "
                     f"joint posterior), got {len(values)}; give one number for a single one")
            return _BAD
        twice = sorted({v for v in values if values.count(v) > 1})
        if twice:
            repeated = ", ".join(f"{v:g}" for v in twice)
            self.add(f"{where}: each half-mode mass once, got {repeated} more than once")
            return _BAD
        return tuple(sorted(values))

    def population(self, out):
        """The population's own bounds (log_m_host, log_mhm), checked by building one
        (one per half-mode mass of a grid)."""
        values = [out[k] for k in ("model", "log_m_host", "log_mhm")]
        if self.problems or not _valid(*values):
            return
        from ..inference import SubhaloPopulation

        masses = out["log_mhm"] if isinstance(out["log_mhm"], tuple) else (out["log_mhm"],)
        for log_mhm in masses:
            try:
                SubhaloPopulation(0.5, 1.0, model=out["model"], log_m_host=out["log_m_host"],
                                  log_mhm=log_mhm)
            except ValueError as exc:
                key = "log_mhm" if "log_mhm" in str(exc) else "log_m_host"
                self.add(f"[inference] {key}: {exc}")
                if key == "log_m_host":
                    return
            except ImportError as exc:
                self.add(f"[inference]: {exc}")
                return

    def bounds(self, value):
        if value is _ABSENT:
            return _d("sigma_sub")
        if (not isinstance(value, list) or len(value) != 2
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                           for v in value)):
            self.add("[inference] sigma_sub: expected [min, max], two numbers in kpc^-2 (e.g. "
                     f"[0.001, 0.3]), got {_describe(value)}")
            return _BAD
        lo, hi = (float(v) for v in value)
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
            self.add(f"[inference] sigma_sub: the bounds must be finite with 0 < min < max "
                     f"(a log-uniform prior), got [{lo:g}, {hi:g}]")
            return _BAD
        return (lo, hi)

    def calibrate(self, table):
        """The calibration switch (default on)."""
        return self.get(table, "calibrate", "inference")

    def weight(self, value):
        if value is _ABSENT:
            return None
        if isinstance(value, str):
            if value != "composite":
                self.add(f'[inference] weight: expected "composite" or a number in (0, 1], '
                         f"got {value!r}{_suggest(value, ['composite'])}")
                return _BAD
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.add('[inference] weight: expected "composite" or a number in (0, 1], got '
                     f"{_describe(value)}")
            return _BAD
        if not 0 < value <= 1:
            self.add(f"[inference] weight: must be in (0, 1], got {value:g}")
            return _BAD
        return float(value)

    def systems(self, mocks):
        value = (self.data.get("inference") or {}).get("system", _ABSENT)
        if not isinstance(self.data.get("inference"), dict):
            return ()
        if value is _ABSENT:
            self.add("[[inference.system]]: missing: give at least one system (a table with "
                     "pairs and lenstool or family)")
            return ()
        if isinstance(value, dict):
            value = [value]
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            self.add(f"[inference] system: expected an array of tables ([[inference.system]]), "
                     f"got {_describe(value)}")
            return ()
        if not value:
            self.add("[[inference.system]]: give at least one system")
            return ()
        systems = [self.system(i, t, mocks) for i, t in enumerate(value)]
        names = [s.name for s in systems if s is not None]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            self.add(f"[[inference.system]] name: the names {twice} are used twice; name "
                     "every system apart (name = \"...\")")
        return tuple(systems)

    def system(self, index, table, mocks):
        sec = f"inference.system #{index + 1}"
        self.unknown_keys(table, _KEYS[_SYSTEM], sec)

        def get(key):
            return self.get(table, key, sec, where=_SYSTEM)

        pairs = get("pairs")
        if pairs is None and "pairs" not in table:
            self.add(f"[{sec}] pairs: required (the pairs.ecsv of lensdual run)")
            pairs = _BAD
        name = get("name")
        lenstool, family, z_source = get("lenstool"), get("family"), get("z_source")
        sigma_pos, flux_rel_err, radius = get("sigma_pos"), get("flux_rel_err"), get("radius")
        if "lenstool" in table and "family" in table:
            self.add(f"[{sec}] family: give the smooth lens once: lenstool (a real model) "
                     "or family (a mock), not both")
        elif "lenstool" not in table and "family" not in table:
            self.add(f"[{sec}] lenstool: missing: give the smooth lens, lenstool = "
                     '"best.par" (or family = "..." for a mock)')
        if "family" in table and "z_source" in table:
            self.add(f"[{sec}] z_source: a family has its own redshifts; give z_source with "
                     "lenstool only")
        model = None if "family" in table else self.lenstool_model(lenstool, z_source, sec,
                                                                   table)
        family_ok = self.family(family, sec)
        tab = self.pairs_table(pairs, sec) if _valid(pairs) and pairs is not None else None
        if tab is not None and model is not None:
            self.lenstool_frame(tab, sec)
        if tab is not None and mocks:
            self.weight_noise(tab, sec, sigma_pos, flux_rel_err, mocks)
        if name is None and _valid(pairs) and pairs is not None:
            name = pairs.stem if pairs.stem != "pairs" else f"{pairs.parent.name}"
        if name is None or not _valid(name, lenstool, family, z_source, sigma_pos,
                                      flux_rel_err, radius) \
                or tab is None or not family_ok:
            return None
        return InferenceSystemSpec(name=name, pairs=pairs, table=tab, lenstool=lenstool,
                                   family=family, z_source=z_source, sigma_pos=sigma_pos,
                                   flux_rel_err=flux_rel_err, radius=radius)

    def lenstool_model(self, path, z_source, sec, table):
        """Read the Lenstool file and check ``z_source`` against its lens redshift."""
        if path is None or path is _BAD:
            return None
        from ..parametric import read_lenstool

        try:
            model = read_lenstool(path)
        except (ValueError, OSError) as exc:
            self.add(f"[{sec}] lenstool: cannot read {path} as a Lenstool model: {exc}")
            return None
        if "z_source" not in table:
            self.add(f"[{sec}] z_source: required with lenstool (the source redshift; the "
                     f"model's lens is at z = {model.z_lens:g})")
        elif isinstance(z_source, float) and not z_source > model.z_lens:
            self.add(f"[{sec}] z_source: must be larger than the Lenstool model's z_lens "
                     f"({model.z_lens:g}), got {z_source:g}")
        return model

    def family(self, family, sec):
        """Whether the lens family can be built (a real model needs its data folder)."""
        if family is None or family is _BAD:
            return family is None
        from ..simulation.families import calibration_system

        try:
            calibration_system(family)
        except (FileNotFoundError, OSError, ValueError) as exc:
            self.add(f"[{sec}] family: cannot build the lens family {family!r}: {exc}")
            return False
        return True

    def pairs_table(self, path, sec):
        """The pairs table, checked to be a duality result with tested pairs."""
        from astropy.table import QTable

        from ..inference import pair_anomalies

        try:
            tab = QTable.read(path, format="ascii.ecsv")
        except Exception as exc:  # any failure means the file is unusable
            self.add(f"[{sec}] pairs: could not read {path} as an ECSV table ({exc})")
            return None
        missing = [c for c in ("x1", "y1", "x2", "y2") if c not in tab.colnames]
        if missing:
            self.add(f"[{sec}] pairs: {path} has no column(s) {', '.join(missing)} (the "
                     "positions of the pairs)")
            return None
        try:
            pair_anomalies(tab)
        except (TypeError, ValueError) as exc:
            self.add(f"[{sec}] pairs: {path}: {exc}")
            return None
        return tab

    def lenstool_frame(self, tab, sec):
        """The pairs need sky positions to be placed in a Lenstool model's frame."""
        has_sky = "sky1" in tab.colnames and "sky2" in tab.colnames
        if not has_sky and tab.meta.get("reference") is None:
            self.add(f"[{sec}] pairs: the table has no sky1, sky2 columns and no "
                     "meta['reference'], so its pairs cannot be placed in the Lenstool "
                     "model's frame")

    def weight_noise(self, tab, sec, sigma_pos, flux_rel_err, mocks):
        """The mocks (composite weight, calibration) need the table's noise, or the keys
        that give it."""
        from .._inference_run import table_flux_rel_err, table_sigma_pos

        if sigma_pos is None and table_sigma_pos(tab) is None:
            self.add(f"[{sec}] sigma_pos: required with {mocks}: the table has "
                     "no scalar sigma_pos of its duality test and no pos_err1, pos_err2 "
                     "columns")
        if flux_rel_err is None and table_flux_rel_err(tab) is None:
            self.add(f"[{sec}] flux_rel_err: required with {mocks}: the table "
                     "has no flux and flux_err columns to measure it")

    def inputs_outside(self, config):
        """The output directory must hold none of the files the run reads."""
        if config.outdir is None:
            return
        where = "outdir (argument)" if self.outdir_arg is not None else "[output] outdir"
        inside = [f for f in config.input_files() if f.is_relative_to(config.outdir)]
        if inside:
            names = ", ".join(str(f.relative_to(config.outdir)) for f in inside[:4])
            more = f" and {len(inside) - 4} more" if len(inside) > 4 else ""
            self.add(f"{where}: the output directory {config.outdir} holds {names}{more}, "
                     "read by this run; a run never replaces or removes its own inputs, so "
                     "choose an output directory that holds none of them")

    def run(self):
        self.check_root()
        outdir = self.output()
        settings = self.inference()
        systems = self.systems(_mocks(settings))
        if settings is not None and not self.problems:
            self.anomaly(settings, systems)
        if self.problems or settings is None:
            raise ConfigError(self.problems, self.path)
        config = InferenceConfig(path=self.path, outdir=outdir, systems=systems, **settings)
        self.inputs_outside(config)
        if self.problems:
            raise ConfigError(self.problems, self.path)
        return config


    def anomaly(self, settings, systems):
        """Resolve ``anomaly = "auto"`` on the systems' tables (in ``settings``); a
        joint anomaly needs every table to be a joint-test table."""
        joint = [s.table.meta.get("duality", {}).get("test", "geometric") == "joint"
                 for s in systems]
        if settings["anomaly"] == "auto":
            settings["anomaly"] = "joint" if all(joint) else "geometric"
            settings["anomaly_source"] = "auto"
        elif settings["anomaly"] == "joint" and not all(joint):
            names = [s.name for s, j in zip(systems, joint, strict=True) if not j]
            self.add('[inference] anomaly: "joint" reads the joint test\'s prediction, and the '
                     f"tables of {', '.join(names)} are of the geometric test (check_duality "
                     'test="joint", or lensdual run with 13 sources or more); use "geometric" '
                     'or "auto"')


def _effective_weight(settings):
    """The weight of the settings: the configured one, else 1 with the calibration and
    "composite" without it."""
    if settings["weight"] is not None:
        return settings["weight"]
    return 1.0 if settings["calibrate"] is True else "composite"


def _mocks(settings):
    """What of the settings makes mocks of each system (None: nothing)."""
    if not settings:
        return None
    if _effective_weight(settings) == "composite":
        return 'weight = "composite"'
    if settings["calibrate"] is True:
        return "calibrate = true"
    return None


def load_inference_config(path, *, outdir=None):
    """Read and validate a ``lensdual infer`` configuration file.

    Every table, key and value is checked, and so are the files they name:
    each pairs table is read and must be a duality result
    (:func:`~lensdual.check_duality`, or ``pairs.ecsv`` of ``lensdual run``)
    with tested pairs; each Lenstool file is read. The keys are described in
    :mod:`lensdual.config` ("The keys of lensdual infer").

    Parameters
    ----------
    path : path-like
        The TOML configuration file.
    outdir : path-like, optional
        The output directory, replacing ``[output] outdir`` (relative to the
        current directory; ``[output] outdir`` is relative to the file's
        directory, default ``lensdual-inference``).

    Returns
    -------
    `InferenceConfig`

    Raises
    ------
    ConfigError
        The file is missing or not valid TOML, or the configuration has
        problems; all of them are listed in the one error.
    """
    cfg_path, data = read_toml(path)
    return _InferenceValidator(data, cfg_path, outdir).run()

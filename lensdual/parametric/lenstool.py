"""Read Lenstool parameter files (``best.par``) and multiple-image catalogues.

Lenstool (Jullo et al. 2007) writes its best-fit model as a ``.par`` file made
of blocks (``runmode``, ``potential``, ``cosmology``, ...), one ``key value``
per line, each block closed by ``end``. :func:`read_lenstool` reads the
potentials of such a file (dPIE, profile 81, NFW, profile 12, and external
shear, profile 14, on one or several lens planes) into a
:class:`LenstoolModel`, which evaluates the deflection and the Hessian with
Numba kernels (:class:`LenstoolLensModel`, a drop-in for lenstronomy's
``LensModel``) and builds a `~lensdual.simulation.LensSystem`.
:func:`read_lenstool_images` reads the multiple-image catalogue (``arcs.dat``)
the model was fitted to.

Conventions (Lenstool's, verified on the SMACS0723 model of Mahler et al.
2023 for the dPIE, taken from the Lenstool 6.8 source for the NFW; see the
"Lenstool models" page of the documentation):

* model frame: ``x = -(RA - RA0) cos(Dec0) * 3600``, ``y = (Dec - Dec0) *
  3600`` arcsec (x grows to the West), linear in RA and Dec around the
  ``runmode`` ``reference``;
* ``angle_pos``: degrees, counter-clockwise from the x axis, to the major axis;
* ``ellipticite`` of profile 81: ``e = (A^2 - B^2) / (A^2 + B^2)`` of the
  surface density, used through ``epsilon = (1 - sqrt(1 - e^2)) / e``;
* ``ellipticite`` of profile 12: the ellipticity ``epsilon`` of the potential,
  ``psi(X, Y) = psi_NFW(sqrt((1 - epsilon) X^2 + (1 + epsilon) Y^2))``
  (Golse & Kneib 2002); ``ellip_pot`` gives ``epsilon = 3 ellip_pot``;
* ``v_disp``: ``b0 = 6 pi (v_disp / c)^2`` (radians; for the dPIE the
  Einstein radius of the singular isothermal limit, for the NFW
  ``4 kappa_s r_s`` with ``v_disp^2 = 8/3 G r_s^2 rho_s``), times
  ``D_ls / D_s``;
* an NFW is defined by the first of (concentration, m200), (concentration,
  r200), (concentration, scale_radius), (scale_radius, m200), (scale_radius,
  r200), m200 alone, (v_disp, scale_radius) that its block gives, with M200
  and r200 relative to 200 times the critical density at ``z_lens``;
* ``*_radius_kpc`` take precedence over the arcsec values when both are given
  (as in Lenstool), converted with the angular diameter distance of the
  potential's own plane in the file's cosmology;
* profile 14 (external shear; ``e_grad.c``, ``e_grad2.c`` case 14,
  ``r_potentiel.c``): ``psi = gamma/2 (X^2 - Y^2) + kappa/2 (X^2 + Y^2)`` with
  X along ``angle_pos`` (degrees counter-clockwise from x, i.e. from West
  towards North: the direction along which images are stretched), about
  ``x_centre``, ``y_centre`` (default 0); ``gamma`` and ``kappa`` are
  multiplied by ``D_ls / D_s`` like every potential (``e_dpl``); lenstronomy's
  ``SHEAR`` with ``gamma1 = gamma cos 2 angle_pos``, ``gamma2 = gamma sin 2
  angle_pos``. ``ellipticite`` is Lenstool's other name for ``gamma``;
  ``kappa`` (a convergence sheet) is dropped by Lenstool 6.8's reader;
* several ``z_lens``: the recursive multi-plane lens equation over the
  distinct planes, each potential's ``b0`` referring to its own plane (see
  `LenstoolModel.lens_model` and :mod:`lensdual.parametric._multiplane`).

Keywords lensdual does not interpret are listed in
`LenstoolModel.ignored_keywords`; unknown ones in the ``runmode`` and
``grille`` blocks draw a `LenstoolKeywordWarning`.
"""

import math
import os
import re
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from astropy import constants as const
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.cosmology import FlatLambdaCDM, LambdaCDM, w0waCDM
from astropy.table import QTable

from .._frames import ARCSEC_PER_RAD as _ARCSEC_PER_RAD
from .._lens.model import LensModelBase, plain_positions
from .._validation import DEFAULT_COSMOLOGY, as_cosmology, as_int, as_positions, as_real
from ..exceptions import LenstoolKeywordWarning
from . import _kernels
from ._multiplane import LenstoolMultiPlaneLensModel

__all__ = ["LenstoolModel", "LenstoolLensModel", "LenstoolMultiPlaneLensModel",
           "DPIELensModel", "LenstoolKeywordWarning", "read_lenstool", "read_lenstool_images"]

_C_KMS = const.c.to_value(u.km / u.s)
#: Columns of the external-shear parameters (profile 14): x_centre, y_centre, theta
#: (rad, angle_pos), gamma, kappa (both already multiplied by D_ls / D_s).
N_SHEAR_PARAMS = 5

# Sections of a Lenstool .par file. Any other section name is an error: a key
# line left outside its block would otherwise open a "section" and silently
# swallow the lines up to the next "end".
_SECTIONS = {
    "runmode", "image", "source", "shapemodel", "shapelimit", "grille", "grid",
    "potentiel", "potential", "limit", "limite", "potfile", "cline", "grande", "observ",
    "champ", "field", "frame", "cosmologie", "cosmology", "dynfile", "msgrid", "sourcelimit",
}
_END_OF_FILE = {"fini", "finish"}
# Words that open a section and are never keys of another section: seeing one of
# them inside a block means that block lacks its "end".
_OPENERS = {
    "runmode", "grille", "potentiel", "potential", "limit", "limite", "potfile", "cline",
    "grande", "champ", "cosmologie", "cosmology",
} | _END_OF_FILE
_POTENTIAL_SECTIONS = {"potentiel", "potential"}

# Keys of a potential block, by profile. ``mag`` and ``lum`` (the galaxy's
# magnitude and luminosity, written by Lenstool for scaled members) and
# ``name`` are kept but play no role in the lensing. Aliases are Lenstool's own
# (r_potentiel.c): for an NFW, Lenstool reads ``core_radius`` into the scale
# radius and ``cut_radius`` into r200.
_KEY_ALIASES = {
    "profil": "profile",
    "ellipticite": "ellipticity",
    "ellipticitymass": "ellipticity",
    "ellipticite_pot": "ellip_pot",
}
_COMMON_KEYS = {
    "profile", "x_centre", "y_centre", "x_centre_wcs", "y_centre_wcs", "ellipticity",
    "ellip_pot", "angle_pos", "z_lens", "mag", "lum",
}
# Profile 14 (external shear): Lenstool reads 'gamma', 'ellipticite' and 'ellipticity'
# into the same field (r_potentiel.c), so the last two are aliases of 'gamma' here.
_SHEAR_KEYS = {
    "profile", "x_centre", "y_centre", "x_centre_wcs", "y_centre_wcs", "angle_pos", "z_lens",
    "gamma", "kappa", "mag", "lum",
}
_PROFILE_KEYS = {
    81: {"core_radius", "core_radius_kpc", "cut_radius", "cut_radius_kpc", "v_disp"},
    12: {"scale_radius", "scale_radius_kpc", "r200", "r200_kpc", "v_disp", "concentration",
         "m200", "rhos", "alpha", "rc_slope"},
}
_PROFILE_ALIASES = {
    81: {},
    12: {"core_radius": "scale_radius", "core_radius_kpc": "scale_radius_kpc",
         "cut_radius": "r200", "cut_radius_kpc": "r200_kpc", "virial_radius": "r200",
         "virial_radius_kpc": "r200_kpc", "c": "concentration", "beta": "concentration",
         "masse": "m200", "mass": "m200", "virial_mass": "m200", "exponent": "alpha",
         "exposant": "alpha"},
    14: {"ellipticity": "gamma"},
}
_TEXT_KEYS = {"name"}
_PROFILE_NAMES = {
    1: "SIS", 8: "PIEMD (not truncated)", 12: "NFW", 13: "Sersic", 14: "external shear",
    15: "Einasto", 16: "Hernquist", 81: "dPIE", 121: "triaxial NFW",
}
_SUPPORTED_PROFILES = {81, 12, 14}

# Lenstool's 1/G (constant.h: INVG = 2.325968e8 Msun / (km/s)^2 / Mpc), used in its
# NFW conversions between (concentration, M200, r200, r_s) and v_disp; 3.8e-4 above
# the CODATA 2018 value. lensdual uses it so as to reproduce Lenstool's numbers.
_LENSTOOL_INVG = 2.325968e8
# Relative tolerance of the consistency check of redundant NFW keys (best.par writes
# v_disp, scale_radius, concentration, m200 and rhos, rounded to 4 digits).
_NFW_CONSISTENCY = 0.01
# Maccio, Dutton & van den Bosch (2008) c(M200) relation, as Lenstool applies it to
# an NFW given by its mass alone: log10 c = 0.830 - 0.098 (log10 M200 - 12).
_MACCIO_A, _MACCIO_B = 0.830, -0.098

_COSMO_KEYS = {
    "model", "h0", "omegam", "omega", "omegax", "lambda", "omegak", "wx", "q", "wa",
}

_FITTED_Z = re.compile(
    r"^#\s*(\S+)\s+z:\s*([-+0-9.eEdD]+)\s+dlsds:\s*([-+0-9.eEdD]+)\s*$")
_CHI2 = re.compile(r"^#\s*Chi2tot\(dof=(\d+)\):\s*([-+0-9.eE]+)")


def _as_path(path, name="path"):
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"{name} must be a str or os.PathLike, got {type(path).__name__}")
    return Path(path)


def _number(token, where, key):
    try:
        value = float(token)
    except ValueError:
        raise ValueError(f"{where}: the value {token!r} of key {key!r} is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"{where}: the value of key {key!r} must be finite, got {token!r}")
    return value


def _system_key(name):
    """Lenstool writes the family of image '4.1' as '4.0' in best.par's header."""
    return name[:-2] if name.endswith(".0") else name


def _split_image_id(ident):
    """'4.1' -> ('4', '1'); 'B200.2a' -> ('B200', '2a'); '1a' -> ('1', 'a')."""
    if "." in ident:
        system, image = ident.rsplit(".", 1)
        return system, image
    m = re.fullmatch(r"(.*?\d)([A-Za-z]+)", ident)
    if m:
        return m.group(1), m.group(2)
    return ident, ""


# --------------------------------------------------------------------------- tokenising


def _blocks(path, lines):
    """Split a .par file into blocks.

    Returns ``(blocks, header)``: ``blocks`` is a list of dicts with ``section``,
    ``label``, ``line`` (1-based line of the section name) and ``items``, a
    list of ``(line, key, tokens)``; ``header`` the comment lines before the
    first block.
    """
    blocks = []
    header = []
    current = None
    for number, raw in enumerate(lines, start=1):
        text = raw.split("#", 1)[0].strip()
        if not text:
            if current is None and not blocks and raw.lstrip().startswith("#"):
                header.append(raw.strip())
            continue
        tokens = text.split()
        word = tokens[0].lower()
        where = f"{path}, line {number}"
        if current is None:
            if word in _END_OF_FILE:
                return blocks, header
            if word == "end":
                raise ValueError(f"{where}: 'end' outside of any block")
            if word not in _SECTIONS:
                raise ValueError(
                    f"{where}: {tokens[0]!r} is not a Lenstool section (expected one of "
                    f"{', '.join(sorted(_SECTIONS))}); a key line outside its block?")
            current = {"section": word, "label": " ".join(tokens[1:]), "line": number,
                       "items": []}
            continue
        if word == "end":
            blocks.append(current)
            current = None
            continue
        if word in _OPENERS:
            raise ValueError(
                f"{where}: {tokens[0]!r} inside block '{current['section']} "
                f"{current['label']}'".rstrip() + f" opened at line {current['line']}: "
                "that block has no 'end'")
        current["items"].append((number, word, tokens[1:]))
    if current is not None:
        raise ValueError(
            f"{path}, line {len(lines)}: end of file inside block '{current['section']} "
            f"{current['label']}'".rstrip() + f" opened at line {current['line']}: "
            "the block has no 'end' (truncated file?)")
    return blocks, header


def _reference(path, blocks):
    runmode = [b for b in blocks if b["section"] == "runmode"]
    if not runmode:
        raise ValueError(f"{path}: no runmode block, so no 'reference' (the sky position of "
                         "the model's origin); read the best.par written by Lenstool")
    for block in runmode:
        for number, key, tokens in block["items"]:
            if key != "reference":
                continue
            where = f"{path}, line {number}, block 'runmode', key 'reference'"
            if len(tokens) != 3:
                raise ValueError(f"{where}: expected 'reference MODE RA DEC', got "
                                 f"{' '.join(tokens)!r}")
            mode = tokens[0]
            if mode == "3":
                ra = _number(tokens[1], where, "reference")
                dec = _number(tokens[2], where, "reference")
                return SkyCoord(ra * u.deg, dec * u.deg, frame="icrs"), 3
            if mode == "1":
                try:
                    sky = SkyCoord(tokens[1], tokens[2], unit=(u.hourangle, u.deg),
                                   frame="icrs")
                except ValueError as exc:
                    raise ValueError(f"{where}: cannot read the sexagesimal position "
                                     f"{tokens[1]} {tokens[2]}: {exc}") from None
                return sky, 1
            raise ValueError(f"{where}: reference mode {mode!r} is not supported (1: "
                             "sexagesimal RA DEC, 3: RA DEC in degrees)")
    raise ValueError(f"{path}, line {runmode[0]['line']}: the runmode block has no "
                     "'reference' (the sky position of the model's origin)")


def _cosmology(path, blocks):
    found = [b for b in blocks if b["section"] in ("cosmology", "cosmologie")]
    if not found:
        return None
    block = found[-1]
    values = {}
    for number, key, tokens in block["items"]:
        where = f"{path}, line {number}, block '{block['section']}'"
        if key not in _COSMO_KEYS:
            raise ValueError(f"{where}: unknown key {key!r} (known: "
                             f"{', '.join(sorted(_COSMO_KEYS))})")
        if len(tokens) != 1:
            raise ValueError(f"{where}: key {key!r} needs one value, got {len(tokens)}")
        values[key] = (_number(tokens[0], where, key), number)
    where = f"{path}, line {block['line']}, block '{block['section']}'"

    def get(names, default):
        for name in names:
            if name in values:
                return values[name][0]
        return default

    h0 = get(("h0",), None)
    if h0 is None:
        raise ValueError(f"{where}: no 'H0'")
    om = get(("omegam", "omega"), 0.3)
    ox = get(("omegax", "lambda"), 0.7)
    w0 = get(("wx", "q"), -1.0)
    wa = get(("wa",), 0.0)
    if "omegak" in values:
        ok = values["omegak"][0]
        if ok != 0.0 and abs(ok - (1.0 - om - ox)) > 1e-6:
            raise ValueError(f"{path}, line {values['omegak'][1]}, block "
                             f"'{block['section']}': omegaK = {ok} is not 1 - omegaM - omegaX "
                             f"= {1.0 - om - ox}")
    if h0 <= 0 or om < 0:
        raise ValueError(f"{where}: H0 must be > 0 and omegaM >= 0, got H0={h0}, omegaM={om}")
    if w0 == -1.0 and wa == 0.0:
        if abs(om + ox - 1.0) < 1e-12:
            return FlatLambdaCDM(H0=h0, Om0=om, Tcmb0=0.0)
        return LambdaCDM(H0=h0, Om0=om, Ode0=ox, Tcmb0=0.0)
    return w0waCDM(H0=h0, Om0=om, Ode0=ox, w0=w0, wa=wa, Tcmb0=0.0)


# Keywords of the blocks lensdual reads (runmode, grille) that it knowingly ignores,
# with the reason ignoring them cannot change the lens model. Any other keyword of these
# blocks draws a LenstoolKeywordWarning. See the table in docs/lenstool.rst.
_OUTPUT = "asks Lenstool for an output (a map, a catalogue or a file); no effect on the model"
_IGNORED_KEYS = {
    "runmode": {
        "image": "asks Lenstool to predict the images of a catalogue (output)",
        "source": "asks Lenstool to lens a source catalogue (output)",
        "mass": _OUTPUT, "dpl": _OUTPUT, "ampli": _OUTPUT, "shear": _OUTPUT,
        "poten": _OUTPUT, "time": _OUTPUT, "pixel": _OUTPUT, "cube": _OUTPUT,
        "arclet": _OUTPUT, "shearfield": _OUTPUT, "radialprop": _OUTPUT, "study": _OUTPUT,
        "marker": _OUTPUT, "amplif": _OUTPUT, "mu": _OUTPUT,
        "inverse": "the optimisation mode of the fit that produced best.par",
        "verbose": "Lenstool's terminal output",
        "debug": "Lenstool's terminal output",
    },
    "grille": {
        "nombre": "size of Lenstool's own evaluation grid (maps, image search)",
        "number": "size of Lenstool's own evaluation grid (maps, image search)",
        "polaire": "polar or Cartesian layout of Lenstool's own evaluation grid",
        "polar": "polar or Cartesian layout of Lenstool's own evaluation grid",
        "nlens_crit": "potentials used by Lenstool's 'snake' critical-line algorithm only",
        "nlens_opt": "number of potentials the fit optimised; best.par lists their values",
    },
}
_IGNORED_KEYS["grid"] = _IGNORED_KEYS["grille"]
# Blocks lensdual does not read at all, and why that is harmless.
_SKIPPED_BLOCKS = {
    "image": "the fit's constraints and redshift priors (z_m_limit); best.par's header has "
             "the fitted redshifts, and the catalogue is read by read_lenstool_images",
    "source": "sources for Lenstool to simulate (output)",
    "cline": "how Lenstool draws critical lines and caustics (output)",
    "grande": "Lenstool's drawing of arcs and iso-contours (output)",
    "champ": "the field of Lenstool's output maps",
    "field": "the field of Lenstool's output maps",
    "frame": "the field of Lenstool's output maps",
    "limit": "the priors of the fit that produced best.par",
    "limite": "the priors of the fit that produced best.par",
    "shapemodel": "source shapes for Lenstool to simulate (output)",
    "shapelimit": "priors of source shapes (fit)",
    "sourcelimit": "priors of source shapes (fit)",
    "observ": "simulated observing conditions (output)",
    "dynfile": "kinematic constraints of the fit",
    "msgrid": "multi-scale grid settings of the fit",
}
_INTERPRETED_KEYS = {"runmode": {"reference"}, "grille": {"nlens", "nlentille"},
                     "grid": {"nlens", "nlentille"}}


def _ignored_keywords(path, blocks):
    """The keywords of ``blocks`` that lensdual does not interpret.

    Returns a `~astropy.table.Table`: ``block``, ``keyword``, ``line`` (the
    first), ``count`` and ``reason``, one row per distinct (block, keyword).
    Keywords of the ``runmode`` and ``grille`` blocks that are neither read
    nor known to be harmless draw one `LenstoolKeywordWarning` each.
    """
    from astropy.table import Table

    seen = {}
    for block in blocks:
        section = block["section"]
        if section in _POTENTIAL_SECTIONS or section in ("cosmology", "cosmologie"):
            continue
        for number, key, _ in block["items"]:
            if key in _INTERPRETED_KEYS.get(section, ()):
                continue
            if section in _SKIPPED_BLOCKS:
                reason = f"block not read: {_SKIPPED_BLOCKS[section]}"
            else:
                reason = _IGNORED_KEYS.get(section, {}).get(key)
            name = (section, key)
            if name in seen:
                seen[name][3] += 1
                continue
            if reason is None:
                reason = "unknown to lensdual: not interpreted"
                warnings.warn(
                    f"{path}, line {number}, block '{section}': keyword {key!r} is not "
                    "interpreted by lensdual (it is not one it knows to be harmless); check "
                    "that it does not change the lens model", LenstoolKeywordWarning,
                    stacklevel=3)
            seen[name] = [section, key, number, 1, reason]
    rows = list(seen.values())
    return Table(rows=rows or None, names=("block", "keyword", "line", "count", "reason"),
                 dtype=(str, str, int, int, str))


def _check_nlens(path, blocks, n_potentials):
    for block in blocks:
        if block["section"] not in ("grille", "grid"):
            continue
        for number, key, tokens in block["items"]:
            if key in ("nlens", "nlentille") and tokens:
                nlens = _number(tokens[0], f"{path}, line {number}, block "
                                f"'{block['section']}'", key)
                if nlens < n_potentials:
                    raise ValueError(
                        f"{path}, line {number}: {key} = {int(nlens)} but the file has "
                        f"{n_potentials} potential blocks; Lenstool would use only the first "
                        f"{int(nlens)}, which this reader does not emulate")


def _block_profile(path, label, where, items):
    """The profile of a potential block and the line and spelling it is given with."""
    found = [it for it in items if it[2] == "profile"]
    if not found:
        raise ValueError(f"{where}: no 'profile'")
    if len(found) > 1:
        raise ValueError(f"{path}, line {found[1][0]}, block '{label}': key 'profile' given "
                         f"twice (first at line {found[0][0]})")
    number, key, _, tokens = found[0]
    pwhere = f"{path}, line {number}, block '{label}', key 'profile'"
    if len(tokens) != 1:
        raise ValueError(f"{path}, line {number}, block '{label}': key {key!r} needs one value, "
                         f"got {len(tokens)} ({' '.join(tokens)!r})")
    profile = _number(tokens[0], f"{path}, line {number}, block '{label}'", key)
    if profile != int(profile):
        raise ValueError(f"{pwhere}: the profile must be an integer, got {profile}")
    profile = int(profile)
    if profile not in _SUPPORTED_PROFILES:
        name = _PROFILE_NAMES.get(profile)
        what = f"profile {profile} ({name})" if name else f"unknown profile {profile}"
        raise ValueError(f"{pwhere}: {what} is not supported (only profile 81, the dPIE, and "
                         "profile 12, the NFW), besides profile 14, the external shear")
    return profile, number, key


def _block_values(path, label, items, profile, number, key):
    """The values of a potential block's keys under their canonical names, with
    the line and the spelling of each (``profile`` given at line ``number`` as
    ``key``)."""
    allowed = _SHEAR_KEYS if profile == 14 else _COMMON_KEYS | _PROFILE_KEYS[profile]
    aliases = _PROFILE_ALIASES[profile]
    values = {"profile": profile}
    lines = {"profile": number}
    spelled = {"profile": key}
    for number, key, canon, tokens in items:
        if canon == "profile":
            continue
        lwhere = f"{path}, line {number}, block '{label}'"
        canon = aliases.get(canon, canon)
        if canon not in allowed and canon not in _TEXT_KEYS:
            known = sorted(allowed | _TEXT_KEYS | set(aliases))
            raise ValueError(f"{lwhere}: unknown key {key!r} in a potential block of profile "
                             f"{profile} ({_PROFILE_NAMES[profile]}; known: "
                             f"{', '.join(known)})")
        if canon in values:
            same = "" if spelled[canon] == key else f", as {spelled[canon]!r}"
            raise ValueError(f"{lwhere}: key {key!r} given twice (first at line "
                             f"{lines[canon]}{same})")
        if len(tokens) != 1:
            raise ValueError(f"{lwhere}: key {key!r} needs one value, got "
                             f"{len(tokens)} ({' '.join(tokens)!r})")
        values[canon] = tokens[0] if canon in _TEXT_KEYS else _number(tokens[0], lwhere, key)
        lines[canon] = number
        spelled[canon] = key
    return values, lines, spelled


def _block_required(path, label, where, values, lines, profile):
    """The keys a potential block of ``profile`` must (and must not both) give."""
    if "z_lens" not in values:
        raise ValueError(f"{where}: no 'z_lens'")
    for pair in (("x_centre", "x_centre_wcs"), ("y_centre", "y_centre_wcs")):
        given = sum(k in values for k in pair)
        # the centre of an external shear only shifts the source plane (Lenstool: 0, 0)
        if given > 1 or (given == 0 and profile != 14):
            raise ValueError(f"{where}: give exactly one of {pair[0]!r} and {pair[1]!r}")
    if profile == 14 and "gamma" not in values:
        raise ValueError(f"{where}: no 'gamma' (the external shear of profile 14)")
    if profile == 81:
        if "v_disp" not in values:
            raise ValueError(f"{where}: no 'v_disp'")
        for pair in (("core_radius", "core_radius_kpc"), ("cut_radius", "cut_radius_kpc")):
            if not any(k in values for k in pair):
                raise ValueError(f"{where}: no {pair[0]!r} (nor {pair[1]!r})")
    if "ellipticity" in values and "ellip_pot" in values:
        raise ValueError(f"{path}, line {lines['ellip_pot']}, block '{label}': give "
                         "'ellipticite' or 'ellip_pot', not both")


def _block_ranges(path, label, values, lines, spelled, profile):
    """Each value of a potential block within its range."""

    def check(key, ok, cond):
        if key in values and not ok(values[key]):
            raise ValueError(f"{path}, line {lines[key]}, block '{label}', key "
                             f"{spelled[key]!r}: must be {cond}, got {values[key]}")

    check("ellipticity", lambda v: 0.0 <= v < 1.0, "in [0, 1)")
    check("gamma", lambda v: 0.0 <= v < 1.0, "in [0, 1) (rotate 'angle_pos' by 90 deg for the "
          "opposite sign)")
    check("kappa", lambda v: v < 1.0, "< 1")
    if profile == 12:
        # Lenstool sets the NFW's ellipticity to 3 * ellip_pot (set_lens.c)
        check("ellip_pot", lambda v: 0.0 <= v < 1.0 / 3.0, "in [0, 1/3) (Lenstool uses "
              "3 * ellip_pot as the ellipticity of an NFW)")
    else:
        check("ellip_pot", lambda v: 0.0 <= v < 1.0, "in [0, 1)")
    check("z_lens", lambda v: v > 0.0, "> 0")
    for key in ("v_disp", "core_radius", "core_radius_kpc", "cut_radius", "cut_radius_kpc",
                "scale_radius", "scale_radius_kpc", "concentration", "m200", "rhos"):
        check(key, lambda v: v >= 0.0, ">= 0 (0: not given)" if profile == 12 else ">= 0")
    for key in ("r200", "r200_kpc"):
        check(key, lambda v: v > 0.0, "> 0")
    check("alpha", lambda v: v in (0.0, 1.0), "0 or 1 (the generalised NFW, alpha != 0 or 1 "
          "in Lenstool, is not supported)")
    check("rc_slope", lambda v: v == 0.0, "0 (not supported for an NFW)")


def _potential(path, block):
    """The keys of one potential block, validated; returns a dict.

    Keys are stored under their canonical names (``_KEY_ALIASES`` and, once
    the profile is known, ``_PROFILE_ALIASES``); ``_lines`` maps them to their
    line and ``_keys`` to the spelling of the file, for the messages. The
    checks run in the order a user fixes them: the profile, each key, the
    keys the profile needs, the ranges.
    """
    label = f"{block['section']} {block['label']}".strip()
    where = f"{path}, line {block['line']}, block '{label}'"
    items = [(number, key, _KEY_ALIASES.get(key, key), tokens)
             for number, key, tokens in block["items"]]
    profile, number, key = _block_profile(path, label, where, items)
    values, lines, spelled = _block_values(path, label, items, profile, number, key)
    _block_required(path, label, where, values, lines, profile)
    _block_ranges(path, label, values, lines, spelled, profile)
    values["_lines"] = lines
    values["_keys"] = spelled
    values["_label"] = label
    values["_name"] = str(values.get("name", block["label"] or f"#{block['line']}"))
    values["_line"] = block["line"]
    return values


def _rho_crit(cosmo, z):
    """Critical density at ``z`` in Msun / Mpc^3, with Lenstool's G."""
    h = cosmo.H(z).to_value(u.km / u.s / u.Mpc)
    return 3.0 * h * h * _LENSTOOL_INVG / (8.0 * math.pi)


def _nfw_delta_c(c):
    """Characteristic overdensity ``rho_s / rho_crit`` of an NFW of concentration ``c``
    (M200 with respect to the critical density)."""
    return 200.0 / 3.0 * c**3 / (math.log1p(c) - c / (1.0 + c))


def _nfw_v_disp(c, rs_mpc, rho_c):
    """Lenstool's NFW velocity dispersion, ``v_disp^2 = 8/3 G r_s^2 rho_s`` (km/s)."""
    return math.sqrt(8.0 / 3.0 / _LENSTOOL_INVG * rs_mpc**2 * _nfw_delta_c(c) * rho_c)


def _r200_from_m200(m200, rho_c):
    """r200 (Mpc) of a mass M200 (Msun): ``M200 = 4/3 pi r200^3 200 rho_crit``."""
    return (3.0 * m200 / (4.0 * math.pi * 200.0 * rho_c)) ** (1.0 / 3.0)


def _nfw_concentration(v_disp, rs_mpc, rho_c):
    """The concentration of an NFW given by ``v_disp`` and ``r_s`` (NaN if none)."""
    from scipy.optimize import brentq

    target = 3.0 / 8.0 * _LENSTOOL_INVG * v_disp**2 / rs_mpc**2 / rho_c
    lo, hi = 1e-6, 1e6
    if not _nfw_delta_c(lo) < target < _nfw_delta_c(hi):
        return math.nan
    return brentq(lambda c: _nfw_delta_c(c) - target, lo, hi, xtol=1e-14, rtol=1e-14)


def _nfw_parameters(path, p, cosmo, z_lens, kpc_per_arcsec):
    """Scale radius and v_disp of an NFW block, the way Lenstool derives them.

    Lenstool (set_dynamics in set_lens.c) takes the first of these
    definitions that the block gives (0 meaning "not given"), and ignores
    the other keys: (concentration, m200), (concentration, r200),
    (concentration, scale_radius), (scale_radius, m200), (scale_radius,
    r200), m200 alone (concentration from Maccio et al. 2008), and else
    (v_disp, scale_radius) as they are. Given keys that the definition does
    not use must agree with it to 1 %.

    Returns a dict: ``rs`` (arcsec), ``rs_kpc``, ``v_disp`` (km/s),
    ``concentration``, ``m200`` (Msun), ``r200_kpc``, ``definition`` (str).
    """
    label = p["_label"]
    where = f"{path}, line {p['_line']}, block '{label}'"
    rho_c = _rho_crit(cosmo, z_lens)

    def given(key):
        value = p.get(key, 0.0)
        return value if value > 0 else None

    c = given("concentration")
    m200 = given("m200")
    r200_kpc = given("r200_kpc")
    if r200_kpc is None and given("r200") is not None:
        r200_kpc = p["r200"] * kpc_per_arcsec
    rs_kpc = given("scale_radius_kpc")
    if rs_kpc is None and given("scale_radius") is not None:
        rs_kpc = p["scale_radius"] * kpc_per_arcsec
    v_disp = given("v_disp")

    if c is not None and m200 is not None:
        definition, used = "concentration, m200", ("concentration", "m200")
        rs_kpc_d = _r200_from_m200(m200, rho_c) / c * 1e3
        c_d = c
    elif c is not None and r200_kpc is not None:
        definition, used = "concentration, r200", ("concentration", "r200")
        rs_kpc_d, c_d = r200_kpc / c, c
    elif c is not None and rs_kpc is not None:
        definition, used = "concentration, scale_radius", ("concentration", "scale_radius")
        rs_kpc_d, c_d = rs_kpc, c
    elif rs_kpc is not None and m200 is not None:
        definition, used = "scale_radius, m200", ("scale_radius", "m200")
        rs_kpc_d = rs_kpc
        c_d = _r200_from_m200(m200, rho_c) * 1e3 / rs_kpc
    elif rs_kpc is not None and r200_kpc is not None:
        definition, used = "scale_radius, r200", ("scale_radius", "r200")
        rs_kpc_d, c_d = rs_kpc, r200_kpc / rs_kpc
    elif m200 is not None:
        definition, used = "m200 (Maccio et al. 2008 concentration)", ("m200",)
        c_d = 10.0 ** (_MACCIO_A + _MACCIO_B * (math.log10(m200) - 12.0))
        rs_kpc_d = _r200_from_m200(m200, rho_c) / c_d * 1e3
    elif v_disp is not None and rs_kpc is not None:
        definition, used = "v_disp, scale_radius", ("v_disp", "scale_radius")
        rs_kpc_d = rs_kpc
        c_d = _nfw_concentration(v_disp, rs_kpc * 1e-3, rho_c)
    else:
        have = [k for k, v in (("concentration", c), ("m200", m200), ("r200", r200_kpc),
                               ("scale_radius", rs_kpc), ("v_disp", v_disp)) if v is not None]
        raise ValueError(
            f"{where}: the NFW (profile 12) is not defined: give one of (concentration, "
            "m200), (concentration, r200), (concentration, scale_radius), (scale_radius, "
            "m200), (scale_radius, r200), m200 alone, or (v_disp, scale_radius); it has "
            f"{', '.join(have) if have else 'none of these'} (0 means not given)")
    if definition.startswith("v_disp"):
        v_disp_d = v_disp
    else:
        v_disp_d = _nfw_v_disp(c_d, rs_kpc_d * 1e-3, rho_c)
    m200_d = 4.0 / 3.0 * math.pi * 200.0 * rho_c * (c_d * rs_kpc_d * 1e-3) ** 3
    rhos_d = _nfw_delta_c(c_d) * rho_c if math.isfinite(c_d) else math.nan
    # (file key, derived value in the unit of that key, unit) of every key
    checks = {
        "concentration": ("concentration", c_d, ""), "m200": ("m200", m200_d, " Msun"),
        "r200": ("r200", c_d * rs_kpc_d / kpc_per_arcsec, " arcsec"),
        "r200_kpc": ("r200", c_d * rs_kpc_d, " kpc"),
        "scale_radius": ("scale_radius", rs_kpc_d / kpc_per_arcsec, " arcsec"),
        "scale_radius_kpc": ("scale_radius", rs_kpc_d, " kpc"),
        "v_disp": ("v_disp", v_disp_d, " km/s"), "rhos": ("rhos", rhos_d, " Msun/Mpc^3"),
    }
    # the kpc radius is the one Lenstool uses when both are given
    skip = {"r200" if given("r200_kpc") else "r200_kpc",
            "scale_radius" if given("scale_radius_kpc") else "scale_radius_kpc"}
    for file_key, (quantity, value_d, unit) in checks.items():
        value = given(file_key)
        if value is None or file_key in skip or quantity in used or not math.isfinite(value_d):
            continue
        rel = abs(value / value_d - 1.0)
        if rel > _NFW_CONSISTENCY:
            raise ValueError(
                f"{path}, line {p['_lines'][file_key]}, block '{label}', key "
                f"{p['_keys'][file_key]!r}: {value:.6g}{unit} disagrees by {rel:.1%} with the "
                f"{value_d:.6g}{unit} implied by {definition} (Lenstool would use "
                f"{definition} and ignore it): remove it or make it consistent")
    return {"rs": rs_kpc_d / kpc_per_arcsec, "rs_kpc": rs_kpc_d, "v_disp": v_disp_d,
            "concentration": c_d, "m200": m200_d, "r200_kpc": c_d * rs_kpc_d,
            "definition": definition}


# --------------------------------------------------------------------------- public API


def _potential_row(path, p, origin, cosmo, kpc):
    """One row of ``LenstoolModel.potentials`` (see ``names`` in :func:`read_lenstool`)."""
    cosd0 = math.cos(origin.dec.radian)
    where = f"{path}, line {p['_line']}, block '{p['_label']}'"
    if "x_centre_wcs" in p:
        dra = (p["x_centre_wcs"] - origin.ra.deg + 180.0) % 360.0 - 180.0
        x = -dra * cosd0 * 3600.0
    else:
        x = p.get("x_centre", 0.0)
    if "y_centre_wcs" in p:
        y = (p["y_centre_wcs"] - origin.dec.deg) * 3600.0
    else:
        y = p.get("y_centre", 0.0)
    nan = math.nan
    gamma = kappa = nan
    if p["profile"] == 14:
        # external shear (e_grad.c, e_grad2.c): psi = gamma/2 (X^2 - Y^2) in the frame
        # of angle_pos, plus kappa/2 (X^2 + Y^2); scaled by D_ls/D_s like the others
        gamma, kappa = p["gamma"], p.get("kappa", 0.0)
        emass = eps = core = cut = v_disp = b0 = nan
        extra = (nan, nan, nan, nan, nan, "gamma, kappa")
    elif p["profile"] == 12:
        nfw = _nfw_parameters(path, p, cosmo, p["z_lens"], kpc)
        # Lenstool's NFW takes its ellipticity in the potential: the value of
        # 'ellipticite', or 3 * 'ellip_pot' (set_lens.c, e_grad.c, e_grad2.c)
        emass = 3.0 * p["ellip_pot"] if "ellip_pot" in p else p.get("ellipticity", 0.0)
        eps = emass
        core = cut = nan
        v_disp = nfw["v_disp"]
        extra = (nfw["rs"], nfw["rs_kpc"], nfw["concentration"], nfw["m200"],
                 nfw["r200_kpc"], nfw["definition"])
    else:
        core = (p["core_radius_kpc"] / kpc if "core_radius_kpc" in p
                else p["core_radius"])
        cut = (p["cut_radius_kpc"] / kpc if "cut_radius_kpc" in p
               else p["cut_radius"])
        if not cut > core:
            raise ValueError(f"{where}: the cut radius ({cut:.6g} arcsec) must be larger "
                             f"than the core radius ({core:.6g} arcsec)")
        if "ellip_pot" in p:
            eps = p["ellip_pot"]
            emass = 2.0 * eps / (1.0 + eps * eps)
        else:
            emass = p.get("ellipticity", 0.0)
            eps = (1.0 - math.sqrt(1.0 - emass * emass)) / emass if emass > 0 else 0.0
        if eps > _kernels.EPS_MAX:
            raise ValueError(f"{where}: ellipticity {emass} (epsilon {eps:.6g}) is too "
                             f"close to 1: epsilon must be <= {_kernels.EPS_MAX} (axis "
                             "ratio 1:2000)")
        v_disp = p["v_disp"]
        extra = (nan, nan, nan, nan, nan, "v_disp, core_radius, cut_radius")
    if p["profile"] != 14:
        b0 = 6.0 * math.pi * (v_disp / _C_KMS) ** 2 * _ARCSEC_PER_RAD
    return (p["_name"], p["_line"], int(p["profile"]), x, y, emass, eps,
            p.get("angle_pos", 0.0), core, cut, core * kpc, cut * kpc, v_disp,
            p["z_lens"], p.get("mag", np.nan), b0, *extra, gamma, kappa)


def read_lenstool(path, *, cosmology=None):
    """Read a Lenstool parameter file (``best.par``) of dPIE, NFW and shear potentials.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.par`` file.
    cosmology : `~astropy.cosmology.Cosmology`, optional
        Overrides the file's ``cosmology`` block. Without either,
        ``lensdual``'s default (flat LambdaCDM, H0 = 70, Om0 = 0.3).

    Returns
    -------
    model : `LenstoolModel`

    Raises
    ------
    ValueError
        Anything that cannot be read unambiguously, with the file, line, block
        and key: a block without ``end`` (truncated file), a non-numeric value,
        an unknown key in a potential block (the keys depend on the profile), a
        profile other than 81 (dPIE), 12 (NFW) and 14 (external shear), no
        ``runmode`` ``reference``, a ``potfile`` block (scaling-relation
        members: the ``best.par`` written by Lenstool lists every member as a
        potential); for a shear: no ``gamma``, ``gamma`` outside [0, 1),
        ``kappa >= 1``; and for an NFW: no complete
        definition, negative values, a generalised NFW (``alpha`` other than 0
        or 1), or a redundant key that disagrees with the definition by more
        than 1 %.

    Notes
    -----
    Only the ``runmode`` (``reference``), ``grille`` (``nlens`` or
    ``nlentille``), ``cosmology`` and ``potential`` blocks are interpreted;
    the others (``image``, ``limit``, ``cline``, ``champ``, ...) are checked
    for their ``end`` and skipped. Every keyword not interpreted is listed in
    `LenstoolModel.ignored_keywords` with the reason ignoring it is harmless;
    one that lensdual does not know, in the ``runmode`` or ``grille`` block,
    draws a `LenstoolKeywordWarning` (once per keyword). Potentials at
    different ``z_lens`` make a multi-plane model (`LenstoolModel.z_planes`).
    The fitted redshifts Lenstool writes in the header of ``best.par``
    (``#4.0 z:2.174644 dlsds:0.720273``) are kept in
    `LenstoolModel.fitted_redshifts`.

    **NFW (profile 12).** Keys (with Lenstool's aliases): ``scale_radius``
    (``core_radius``), ``scale_radius_kpc``, ``r200`` (``virial_radius``,
    ``cut_radius``), ``r200_kpc``, ``concentration`` (``c``, ``beta``),
    ``m200`` (``masse``, ``mass``, ``virial_mass``; Msun), ``v_disp``
    (km/s), ``rhos`` (Msun/Mpc^3, informative), ``alpha`` (0 or 1) and
    ``rc_slope`` (0), besides the centre, ``ellipticite`` or ``ellip_pot``
    and ``angle_pos``. As in Lenstool, 0 means "not given", and the profile
    is defined by the first of (concentration, m200), (concentration, r200),
    (concentration, scale_radius), (scale_radius, m200), (scale_radius,
    r200), m200 alone (concentration from Maccio et al. 2008,
    ``log10 c = 0.830 - 0.098 (log10 M200 - 12)``) and (v_disp,
    scale_radius). The conversions are those of Lenstool's ``e_nfw.c``:
    ``M200 = 800/3 pi rho_c r200^3``, ``r_s = r200 / c``, ``rho_s = 200/3
    c^3 / (ln(1 + c) - c / (1 + c)) rho_c`` and ``v_disp^2 = 8/3 G r_s^2
    rho_s``, with ``rho_c = 3 H(z_lens)^2 / (8 pi G)`` in the file's
    cosmology and Lenstool's ``G`` (``1 / 2.325968e8`` Mpc (km/s)^2 / Msun).
    Other keys given (``best.par`` lists ``v_disp``, ``scale_radius``,
    ``concentration``, ``m200`` and ``rhos`` together) must agree with the
    definition to 1 %, or the file is ambiguous and rejected.
    """
    path = _as_path(path)
    cosmo_override = None if cosmology is None else as_cosmology(cosmology)
    lines = path.read_text(encoding="utf-8-sig", errors="replace").splitlines()
    blocks, header = _blocks(path, lines)
    origin, ref_mode = _reference(path, blocks)
    file_cosmology = _cosmology(path, blocks)
    if cosmo_override is not None:
        cosmo = cosmo_override
    else:
        cosmo = file_cosmology if file_cosmology is not None else DEFAULT_COSMOLOGY

    for block in blocks:
        if block["section"] == "potfile":
            raise ValueError(
                f"{path}, line {block['line']}: potfile blocks (members from a galaxy "
                "catalogue and scaling relations) are not supported; read the best.par "
                "written by Lenstool, which lists every member as a potential")
    pots = [_potential(path, b) for b in blocks if b["section"] in _POTENTIAL_SECTIONS]
    if not pots:
        raise ValueError(f"{path}: no potential block")
    _check_nlens(path, blocks, len(pots))
    ignored = _ignored_keywords(path, blocks)

    z_planes = tuple(sorted({p["z_lens"] for p in pots}))
    z_lens = z_planes[0]
    kpc_per_arcsec = {z: cosmo.angular_diameter_distance(z).to_value(u.kpc) / _ARCSEC_PER_RAD
                      for z in z_planes}

    rows = [_potential_row(path, p, origin, cosmo, kpc_per_arcsec[p["z_lens"]]) for p in pots]
    names = ("name", "line", "profile", "x_centre", "y_centre", "ellipticity", "epsilon",
             "angle_pos", "core_radius", "cut_radius", "core_radius_kpc", "cut_radius_kpc",
             "v_disp", "z_lens", "mag", "b0", "scale_radius", "scale_radius_kpc",
             "concentration", "m200", "r200_kpc", "definition", "gamma", "kappa")
    units = (None, None, None, u.arcsec, u.arcsec, None, None, u.deg, u.arcsec, u.arcsec,
             u.kpc, u.kpc, u.km / u.s, None, None, u.arcsec, u.arcsec, u.kpc, None, u.Msun,
             u.kpc, None, None, None)
    cols = list(zip(*rows, strict=True))
    table = QTable()
    for name, col, unit in zip(names, cols, units, strict=True):
        table[name] = np.array(col) * unit if unit is not None else np.array(col)
    table["b0"].description = "6 pi (v_disp / c)^2 for D_ls / D_s = 1"
    table["definition"].description = "the keys that define the potential"
    table["gamma"].description = "external shear (profile 14) for D_ls / D_s = 1"
    table["kappa"].description = "external convergence (profile 14) for D_ls / D_s = 1"

    fitted = {}
    meta = {}
    for line in header:
        m = _FITTED_Z.match(line)
        if m:
            fitted[_system_key(m.group(1))] = float(m.group(2))
            continue
        m = _CHI2.match(line)
        if m:
            meta["chi2"] = float(m.group(2))
            meta["dof"] = int(m.group(1))
    return LenstoolModel(path=path, origin=origin, cosmology=cosmo, z_lens=z_lens,
                         potentials=table, fitted_redshifts=fitted, reference_mode=ref_mode,
                         meta=meta, ignored=ignored)


class LenstoolModel:
    """A Lenstool model: dPIE and NFW potentials around a sky reference.

    Made by :func:`read_lenstool`; not meant to be built by hand.

    Parameters
    ----------
    path, origin, cosmology, z_lens, potentials, fitted_redshifts, reference_mode, meta
        The attributes of the same names (keyword-only).
    ignored : `~astropy.table.Table` or None
        Becomes ``ignored_keywords``.

    Attributes
    ----------
    path : `~pathlib.Path`
        The file it was read from.
    origin : `~astropy.coordinates.SkyCoord`
        The ``runmode`` ``reference``: the origin of the model frame (ICRS).
    cosmology : `~astropy.cosmology.Cosmology`
        The file's cosmology (or the override given to :func:`read_lenstool`).
    z_lens : float
        Redshift of the main (lowest) lens plane: the cluster's.
    z_planes : tuple of float
        The distinct ``z_lens`` of the potentials, increasing (one for a
        single-plane model); see `lens_model` for the multi-plane lens
        equation.
    potentials : `~astropy.table.QTable`
        One row per potential, in file order: ``name``, ``line`` (of the
        block in the file), ``profile`` (81: dPIE, 12: NFW), ``x_centre``,
        ``y_centre`` (arcsec, model frame), ``ellipticity`` (the file's
        ``ellipticite``: for a dPIE the mass ellipticity ``(A^2 - B^2) /
        (A^2 + B^2)``, for an NFW the ellipticity of the potential),
        ``epsilon`` (the ellipticity parameter of the kernels: dPIE ``(A - B)
        / (A + B)`` of the mass, NFW the ellipticity of the potential),
        ``angle_pos`` (deg), ``core_radius``, ``cut_radius`` (arcsec, the
        values used; NaN for an NFW), ``core_radius_kpc``,
        ``cut_radius_kpc``, ``v_disp`` (km/s; for an NFW the value derived
        from its definition), ``z_lens``, ``mag`` (NaN if absent), ``b0``
        (arcsec, ``6 pi (v_disp / c)^2`` for ``D_ls / D_s = 1``), and for the
        NFWs (NaN for the dPIEs) ``scale_radius`` (arcsec),
        ``scale_radius_kpc``, ``concentration``, ``m200`` (Msun, with
        respect to 200 times the critical density at ``z_lens``),
        ``r200_kpc``; ``definition`` names the keys that defined the
        potential (see :func:`read_lenstool`); ``gamma`` and ``kappa``, the
        external shear and convergence of a profile 14 (for ``D_ls / D_s =
        1``; NaN for the other profiles, which have NaN ``b0`` and
        ``v_disp`` in turn).
    fitted_redshifts : dict
        System name -> best-fit redshift, from the header of ``best.par``
        (systems whose redshift Lenstool optimised).
    reference_mode : int
        The ``reference`` mode of the file: 3 (degrees) or 1 (sexagesimal).
    meta : dict
        ``chi2`` and ``dof`` from the header, when present.
    ignored_keywords : `~astropy.table.Table`
        The keywords of the file that lensdual does not interpret: ``block``,
        ``keyword``, ``line`` (first), ``count`` and ``reason`` (why ignoring
        it cannot change the model, or that it is unknown: those drew a
        `LenstoolKeywordWarning`).
    """

    def __init__(self, *, path, origin, cosmology, z_lens, potentials, fitted_redshifts,
                 reference_mode, meta, ignored=None):
        self.path = path
        self.origin = origin
        self.cosmology = cosmology
        self.z_lens = z_lens
        self.potentials = potentials
        self.fitted_redshifts = dict(fitted_redshifts)
        self.reference_mode = reference_mode
        self.meta = dict(meta)
        self.ignored_keywords = ignored
        self.z_planes = tuple(sorted({float(z) for z in np.asarray(potentials["z_lens"])}))

    def __len__(self):
        return len(self.potentials)

    def __repr__(self):
        profiles = np.asarray(self.potentials["profile"])
        n_dpie, n_nfw = int(np.sum(profiles == 81)), int(np.sum(profiles == 12))
        n_shear = int(np.sum(profiles == 14))
        what = (f"{n_dpie} dPIE" + (f" + {n_nfw} NFW" if n_nfw else "")
                + (f" + {n_shear} external shear" if n_shear else ""))
        where = (f"z_lens={self.z_lens}" if len(self.z_planes) == 1 else
                 f"z_lens={self.z_lens} (planes {', '.join(map(str, self.z_planes))})")
        return (f"<LenstoolModel {self.path.name!r}: {what} potentials at "
                f"{where}, origin RA={self.origin.ra.deg:.6f} "
                f"Dec={self.origin.dec.deg:.6f} deg>")

    # ------------------------------------------------------------------ frames

    def to_model_frame(self, sky):
        """Model-frame positions (arcsec) of sky coordinates.

        Lenstool's frame: ``x = -(RA - RA0) cos(Dec0) * 3600``,
        ``y = (Dec - Dec0) * 3600`` (x to the West, y to the North).

        Parameters
        ----------
        sky : `~astropy.coordinates.SkyCoord`
            Scalar or 1-d.

        Returns
        -------
        xy : `~astropy.units.Quantity`, shape (N, 2)
        """
        if not isinstance(sky, SkyCoord):
            raise TypeError(f"sky must be a SkyCoord, got {type(sky).__name__}")
        icrs = sky.icrs
        ra = np.atleast_1d(icrs.ra.deg)
        dec = np.atleast_1d(icrs.dec.deg)
        if ra.ndim != 1:
            raise ValueError(f"sky must be scalar or 1-d, got shape {sky.shape}")
        dra = (ra - self.origin.ra.deg + 180.0) % 360.0 - 180.0
        x = -dra * math.cos(self.origin.dec.radian) * 3600.0
        y = (dec - self.origin.dec.deg) * 3600.0
        return np.column_stack([x, y]) * u.arcsec

    def to_sky(self, xy):
        """Sky coordinates (ICRS) of model-frame positions; inverse of `to_model_frame`.

        Parameters
        ----------
        xy : `~astropy.units.Quantity`, shape (N, 2)
            Angles in the model frame.

        Returns
        -------
        sky : `~astropy.coordinates.SkyCoord`, shape (N,)
        """
        arr = as_positions(xy, "xy")
        ra = self.origin.ra.deg - arr[:, 0] / (3600.0 * math.cos(self.origin.dec.radian))
        dec = self.origin.dec.deg + arr[:, 1] / 3600.0
        return SkyCoord(ra % 360.0 * u.deg, dec * u.deg, frame="icrs")

    # ------------------------------------------------------------------ lensing

    def dls_ds(self, z_source, *, z_lens=None):
        """``D_ls / D_s`` for a source at ``z_source`` (> ``z_lens``).

        ``z_lens`` defaults to the main plane, `z_lens`; give another of
        `z_planes` for the ratio of that plane.

        Parameters
        ----------
        z_source : float
            Source redshift.
        z_lens : float, optional
            Lens-plane redshift (default the main plane's).

        Returns
        -------
        ratio : float
        """
        zs = as_real(z_source, "z_source")
        zl = self.z_lens if z_lens is None else as_real(z_lens, "z_lens")
        if not zs > zl:
            raise ValueError(f"z_source must be larger than z_lens = {zl}, got "
                             f"z_source={z_source}")
        d_ls = self.cosmology.angular_diameter_distance(zl, zs)
        d_s = self.cosmology.angular_diameter_distance(zs)
        return float((d_ls / d_s).to_value(u.dimensionless_unscaled))

    def kernel_parameters(self, z_source=None, *, profile=81, z_plane=None):
        """The float array the kernels take for the potentials of one profile.

        Parameters
        ----------
        z_source : float, optional
            Source redshift: the normalisations are multiplied by
            ``D_ls / D_s`` (not scaled when None), each with the ``D_ls`` of
            its own plane; potentials at or behind the source get 0 (they do
            not lens it).
        profile : {81, 12, 14}
            81 (dPIE): shape (M, 7), columns ``x_centre, y_centre, theta
            (rad), epsilon, core, cut, b0`` (arcsec). 12 (NFW): shape (K, 6),
            columns ``x_centre, y_centre, theta (rad), epsilon, r_s, b0``
            (arcsec; ``epsilon`` the ellipticity of the potential). 14
            (external shear): shape (S, 5), columns ``x_centre, y_centre,
            theta (rad), gamma, kappa``. M, K or S may be 0.
        z_plane : float, optional
            Only the potentials of this plane (one of `z_planes`); by default
            all of them. For a multi-plane model, ``z_source`` given and no
            ``z_plane``, the parameters are those of the single-plane sum in
            which each potential is scaled by its own plane's ``D_ls / D_s``
            (what Lenstool 6.8 does for the Hessian), not the multi-plane lens
            equation of `lens_model`.

        Returns
        -------
        params : `~numpy.ndarray`
            Shape (M, 7), (K, 6) or (S, 5), as described for ``profile``.
        """
        if profile not in (81, 12, 14):
            raise ValueError(f"profile must be 81 (dPIE), 12 (NFW) or 14 (external shear), "
                             f"got {profile!r}")
        sel = np.asarray(self.potentials["profile"]) == profile
        if z_plane is not None:
            if float(z_plane) not in self.z_planes:
                raise ValueError(f"z_plane must be one of the model's planes {self.z_planes}, "
                                 f"got {z_plane!r}")
            sel &= np.asarray(self.potentials["z_lens"], dtype=float) == float(z_plane)
        t = self.potentials[sel]
        ncol = {81: _kernels.N_PARAMS, 12: _kernels.NFW_N_PARAMS, 14: N_SHEAR_PARAMS}[profile]
        if not len(t):
            return np.empty((0, ncol))
        z_of = np.asarray(t["z_lens"], dtype=float)
        if z_source is None:
            scale = 1.0
        elif len(self.z_planes) == 1 or z_plane is not None:
            scale = self.dls_ds(z_source, z_lens=z_of[0])
        else:
            zs = as_real(z_source, "z_source")
            if not zs > self.z_lens:
                raise ValueError(f"z_source must be larger than z_lens = {self.z_lens}, got "
                                 f"z_source={z_source}")
            ratio = {z: (self.dls_ds(zs, z_lens=z) if z < zs else 0.0) for z in set(z_of)}
            scale = np.array([ratio[z] for z in z_of])
        base = [t["x_centre"].to_value(u.arcsec), t["y_centre"].to_value(u.arcsec),
                t["angle_pos"].to_value(u.rad)]
        if profile == 14:
            params = np.column_stack([*base, np.asarray(t["gamma"], dtype=float) * scale,
                                      np.asarray(t["kappa"], dtype=float) * scale])
        else:
            radii = (("core_radius", "cut_radius") if profile == 81 else ("scale_radius",))
            params = np.column_stack([
                *base, np.asarray(t["epsilon"], dtype=float),
                *(t[r].to_value(u.arcsec) for r in radii), t["b0"].to_value(u.arcsec) * scale,
            ])
        return np.ascontiguousarray(params, dtype=np.float64)

    def lens_model(self, z_source, *, n_threads=1):
        """The deflection model for sources at ``z_source``.

        For a single-plane model (or a source in front of every plane but
        the first) a `LenstoolLensModel` whose normalisations are scaled by
        ``D_ls / D_s``. With potentials on two or more planes in front of the
        source, a `LenstoolMultiPlaneLensModel` that solves the recursive
        multi-plane lens equation

        .. math::

            \\theta_j = \\theta - \\sum_{i<j} \\frac{D_{ij}}{D_j}
            \\hat\\alpha_i(\\theta_i), \\qquad
            \\beta = \\theta - \\sum_i \\frac{D_{is}}{D_s} \\hat\\alpha_i(\\theta_i),

        with :math:`\\hat\\alpha_i` the deflection of the potentials of plane
        ``i`` for :math:`D_{ls}/D_s = 1` (their ``b0``), angular diameter
        distances from the model's cosmology; its Hessian is the full
        multi-plane Jacobian. Planes at or behind the source are left out.

        Parameters
        ----------
        z_source : float
            Source redshift, > ``z_lens``.
        n_threads : int
            Threads the Numba kernels run on for large inputs (the kernels
            release the GIL).

        Returns
        -------
        model : `LenstoolLensModel` or `LenstoolMultiPlaneLensModel`
            lenstronomy ``LensModel``-like (``ray_shooting``, ``alpha``,
            ``hessian``, ``magnification``, ``kappa``), model-frame arcsec.
        """
        zs = as_real(z_source, "z_source")
        if not zs > self.z_lens:
            raise ValueError(f"z_source must be larger than z_lens = {self.z_lens}, got "
                             f"z_source={z_source}")
        planes = [z for z in self.z_planes if z < zs]
        if len(self.z_planes) == 1:
            return LenstoolLensModel(self.kernel_parameters(z_source, profile=81),
                                     self.kernel_parameters(z_source, profile=12),
                                     shear=self.kernel_parameters(z_source, profile=14),
                                     n_threads=n_threads, z_source=float(z_source))
        if len(planes) == 1:
            zp = planes[0]
            return LenstoolLensModel(
                *(self.kernel_parameters(z_source, profile=k, z_plane=zp) for k in (81, 12)),
                shear=self.kernel_parameters(z_source, profile=14, z_plane=zp),
                n_threads=n_threads, z_source=float(z_source))
        from ._multiplane import plane_distance_ratios

        models = [LenstoolLensModel(
            *(self.kernel_parameters(None, profile=k, z_plane=zp) for k in (81, 12)),
            shear=self.kernel_parameters(None, profile=14, z_plane=zp), n_threads=n_threads)
            for zp in planes]
        ratios = plane_distance_ratios(self.cosmology, planes, zs)
        return LenstoolMultiPlaneLensModel(models, planes, ratios, z_source=float(z_source))

    def lens_system(self, z_source, *, sources=None, n_threads=1):
        """A `~lensdual.simulation.LensSystem` of this model for ``z_source``.

        Positions of the system are in the model frame (arcsec); use
        `to_model_frame` and `to_sky` to go to and from the sky. Its
        ``kwargs_lens`` list the centres of the potentials (``center_x``,
        ``center_y``), dPIEs first, then NFWs: the model ignores them, the
        image finder refines its grid around them.

        Parameters
        ----------
        z_source : float
            Source redshift, > ``z_lens``.
        sources : `~astropy.units.Quantity`, shape (M, 2), optional
            Source-plane positions of a constellation (see
            `~lensdual.simulation.LensSystem`).
        n_threads : int
            See `lens_model`.

        Returns
        -------
        system : `~lensdual.simulation.LensSystem`
        """
        from .._lens.system import LensSystem

        model = self.lens_model(z_source, n_threads=n_threads)
        kwargs = [{"center_x": float(x), "center_y": float(y)} for x, y in model.centres]
        return LensSystem.from_model(model, kwargs, z_lens=self.z_lens, z_source=z_source,
                                     cosmology=self.cosmology, sources=sources,
                                     label=f"Lenstool model {self.path.name}")


class LenstoolLensModel(LensModelBase):
    """Sum of dPIE, NFW and external-shear potentials, lenstronomy ``LensModel``-like.

    Positions are plain float arrays (any shape, broadcast together) in
    arcsec in the model frame; every method takes lenstronomy's ``kwargs``
    argument and ignores it. Evaluated by the Numba kernels of
    ``lensdual.parametric._kernels``: `alpha`, `hessian` and ``kappa`` (a
    closed form); ``ray_shooting``, ``gamma`` and ``magnification`` follow
    from the first two. Made by `LenstoolModel.lens_model`.

    Parameters
    ----------
    dpie : numpy.ndarray, shape (M, 7), optional
        ``x_centre, y_centre, theta (rad), epsilon, core, cut, b0`` per dPIE
        (see `LenstoolModel.kernel_parameters`).
    nfw : numpy.ndarray, shape (K, 6), optional
        ``x_centre, y_centre, theta (rad), epsilon, r_s, b0`` per NFW.
    shear : numpy.ndarray, shape (S, 5), optional
        ``x_centre, y_centre, theta (rad), gamma, kappa`` per external shear
        (Lenstool's profile 14): the potential ``gamma / 2 (X^2 - Y^2) +
        kappa / 2 (X^2 + Y^2)`` about the centre, X along ``theta``. Linear,
        so evaluated in numpy.
    n_threads : int
        Threads used for inputs of more than 65536 points.
    z_source : float or None
        Kept for reference.
    """

    _MIN_POINTS_PER_THREAD = 32768

    def __init__(self, dpie=None, nfw=None, *, shear=None, n_threads=1, z_source=None):
        self.params = self._checked(dpie, _kernels.N_PARAMS, "dpie")
        self.nfw_params = self._checked(nfw, _kernels.NFW_N_PARAMS, "nfw")
        self.shear_params = self._checked(shear, N_SHEAR_PARAMS, "shear")
        if len(self.params) + len(self.nfw_params) + len(self.shear_params) == 0:
            raise ValueError("the model needs at least one component (dpie, nfw or shear)")
        eps = self.params[:, _kernels.P_EPS]
        core = self.params[:, _kernels.P_CORE]
        cut = self.params[:, _kernels.P_CUT]
        if (eps < 0).any() or (eps > _kernels.EPS_MAX).any():
            raise ValueError(f"epsilon (column 3) must be in [0, {_kernels.EPS_MAX}]")
        if (core < 0).any() or not (cut > core).all():
            raise ValueError("the radii must satisfy 0 <= core < cut (columns 4 and 5)")
        eps = self.nfw_params[:, _kernels.NFW_EPS]
        if (eps < 0).any() or (eps >= 1).any():
            raise ValueError("the NFW epsilon (nfw column 3) must be in [0, 1)")
        if not (self.nfw_params[:, _kernels.NFW_RS] > 0).all():
            raise ValueError("the NFW scale radius (nfw column 4) must be > 0")
        self.n_threads = as_int(n_threads, "n_threads", minimum=1)
        self.z_source = z_source

    @staticmethod
    def _checked(params, ncol, name):
        if params is None:
            return np.empty((0, ncol))
        arr = np.array(params, dtype=np.float64, order="C")
        if arr.ndim != 2 or arr.shape[1] != ncol:
            raise ValueError(f"{name} must have shape (M, {ncol}), got {np.shape(params)}")
        if not np.isfinite(arr).all():
            raise ValueError(f"{name} must be finite")
        arr.flags.writeable = False
        return arr

    @property
    def centres(self):
        """Centres ``(x, y)`` of the mass components, dPIEs then NFWs, shape (M + K, 2)
        (an external shear has no centre of mass and is not listed)."""
        return np.concatenate([self.params[:, :2], self.nfw_params[:, :2]])

    def __repr__(self):
        shear = f" + {len(self.shear_params)} shear" if len(self.shear_params) else ""
        return (f"<{type(self).__name__} {len(self.params)} dPIE + {len(self.nfw_params)} NFW"
                f"{shear} components, z_source={self.z_source}>")

    def _evaluate(self, kernels, x, y):
        dpie_kernel, nfw_kernel, shear_kind = kernels
        out = None
        if len(self.params):
            out = dpie_kernel(x, y, self.params)
        if len(self.nfw_params):
            more = nfw_kernel(x, y, self.nfw_params)
            out = more if out is None else out + more
        if len(self.shear_params):
            more = _shear(x, y, self.shear_params, shear_kind)
            out = more if out is None else out + more
        return out

    def _run(self, kernels, x, y):
        xb, yb = plain_positions(x, y)
        shape = xb.shape
        xf = np.ascontiguousarray(xb.ravel())
        yf = np.ascontiguousarray(yb.ravel())
        n = xf.size
        chunks = min(self.n_threads, max(1, n // self._MIN_POINTS_PER_THREAD))
        if chunks <= 1:
            out = self._evaluate(kernels, xf, yf)
        else:
            edges = np.linspace(0, n, chunks + 1).astype(int)
            with ThreadPoolExecutor(max_workers=chunks) as pool:
                parts = list(pool.map(
                    lambda k: self._evaluate(kernels, xf[edges[k]:edges[k + 1]],
                                             yf[edges[k]:edges[k + 1]]), range(chunks)))
            out = np.concatenate(parts)
        return out, shape

    @staticmethod
    def _shaped(col, shape):
        res = col.reshape(shape)
        return res[()] if shape == () else res

    # the LensModel methods below show LensModelBase's docstrings
    def alpha(self, x, y, kwargs=None, k=None):
        out, shape = self._run((_kernels.dpie_deflection, _kernels.nfw_deflection, "alpha"),
                               x, y)
        return self._shaped(out[:, 0], shape), self._shaped(out[:, 1], shape)

    def hessian(self, x, y, kwargs=None, k=None, diff=None):
        out, shape = self._run((_kernels.dpie_hessian, _kernels.nfw_hessian, "hessian"), x, y)
        fxy = self._shaped(out[:, 1], shape)
        return self._shaped(out[:, 0], shape), fxy, fxy, self._shaped(out[:, 2], shape)

    def alpha_hessian(self, x, y, kwargs=None):
        out, shape = self._run((_kernels.dpie_deflection_hessian,
                                _kernels.nfw_deflection_hessian, "both"), x, y)
        return tuple(self._shaped(out[:, i], shape) for i in range(5))

    def _kappa(self, x, y):
        """The convergence in closed form (the kernels' own, not from the Hessian)."""
        out, shape = self._run((_kernels.dpie_convergence, _kernels.nfw_convergence, "kappa"),
                               x, y)
        return self._shaped(out, shape)


def _shear(x, y, shear, kind):
    """External shear and convergence (profile 14), summed over the rows of ``shear``.

    ``kind``: "alpha" (N, 2), "hessian" (N, 3: f_xx, f_xy, f_yy), "both" (N, 5) or
    "kappa" (N,). With ``c = cos 2 theta``, ``s = sin 2 theta``: f_xx = kappa + gamma c,
    f_xy = gamma s, f_yy = kappa - gamma c, and alpha = f . (x - x_centre).
    """
    c2 = np.cos(2.0 * shear[:, 2])
    s2 = np.sin(2.0 * shear[:, 2])
    gam = shear[:, 3]
    kap = shear[:, 4]
    fxx, fxy, fyy = kap + gam * c2, gam * s2, kap - gam * c2
    if kind == "kappa":
        return np.full(x.shape, kap.sum())
    hess = np.broadcast_to(np.array([fxx.sum(), fxy.sum(), fyy.sum()]), (x.size, 3))
    if kind == "hessian":
        return hess.copy()
    dx = x[:, None] - shear[None, :, 0]
    dy = y[:, None] - shear[None, :, 1]
    alpha = np.column_stack([(fxx * dx + fxy * dy).sum(axis=1),
                             (fxy * dx + fyy * dy).sum(axis=1)])
    if kind == "alpha":
        return alpha
    return np.concatenate([alpha, hess], axis=1)


class DPIELensModel(LenstoolLensModel):
    """A sum of dPIE potentials only (a `LenstoolLensModel` without NFWs).

    Parameters
    ----------
    params : numpy.ndarray, shape (M >= 1, 7)
        ``x_centre, y_centre, theta (rad), epsilon, core, cut, b0`` per
        component (see `LenstoolModel.kernel_parameters`).
    n_threads : int
        Threads used for inputs of more than 65536 points.
    z_source : float or None
        Kept for reference.
    """

    def __init__(self, params, *, n_threads=1, z_source=None):
        arr = np.asarray(params, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[1] != _kernels.N_PARAMS or arr.shape[0] == 0:
            raise ValueError(f"params must have shape (M >= 1, {_kernels.N_PARAMS}), got "
                             f"{np.shape(params)}")
        super().__init__(arr, None, n_threads=n_threads, z_source=z_source)

    def __repr__(self):
        return f"<DPIELensModel {len(self.params)} components, z_source={self.z_source}>"


def _catalogue_reference(tokens, text, where):
    """The frame of a ``#REFERENCE`` line: None (absolute degrees) or its SkyCoord."""
    if len(tokens) < 2 or tokens[1] not in ("0", "1", "3"):
        raise ValueError(f"{where}: expected '#REFERENCE 0', '#REFERENCE 1 RA DEC' "
                         f"or '#REFERENCE 3 RA DEC', got {text!r}")
    if tokens[1] == "0":
        return None
    if len(tokens) != 4:
        raise ValueError(f"{where}: '#REFERENCE {tokens[1]}' needs RA and DEC")
    if tokens[1] == "3":
        return SkyCoord(_number(tokens[2], where, "RA") * u.deg,
                        _number(tokens[3], where, "DEC") * u.deg, frame="icrs")
    return SkyCoord(tokens[2], tokens[3], unit=(u.hourangle, u.deg), frame="icrs")


def _image_values(tokens, where):
    """RA, DEC, a, b, theta, z and mag (NaN when not given) of one image line."""
    cols = ("RA", "DEC", "a", "b", "theta", "z", "mag")
    vals = [_number(tok, where, col) for tok, col in zip(tokens[1:], cols, strict=False)]
    if len(vals) == 6:
        vals.append(np.nan)
    if vals[5] < 0:
        raise ValueError(f"{where}: the redshift must be >= 0 (0: unknown), got {vals[5]}")
    return vals


def _catalogue_sky(path, c1, c2, ref):
    """Sky positions of the catalogue columns RA, DEC (degrees, or arcsec from ``ref``)."""
    if ref is None:
        if ((c2 < -90) | (c2 > 90)).any():
            raise ValueError(f"{path}: DEC outside [-90, 90] deg; a relative catalogue needs a "
                             "'#REFERENCE 3 RA DEC' header")
        return SkyCoord(c1 * u.deg, c2 * u.deg, frame="icrs")
    ra = ref.ra.deg - c1 / (3600.0 * math.cos(ref.dec.radian))
    dec = ref.dec.deg + c2 / 3600.0
    return SkyCoord(ra % 360.0 * u.deg, dec * u.deg, frame="icrs")


def read_lenstool_images(path, *, reference):
    """Read a Lenstool multiple-image catalogue (``arcs.dat``).

    One image per line: ``id RA DEC a b theta z [mag]``. Without a header the
    positions are absolute RA and Dec in degrees; a ``#REFERENCE 3 RA0 DEC0``
    (or ``#REFERENCE 1`` with a sexagesimal reference) header makes them
    arcsec relative to that reference in Lenstool's frame, ``#REFERENCE 0``
    means absolute degrees. Other ``#`` lines are comments.

    Parameters
    ----------
    path : str or os.PathLike
        The catalogue.
    reference : `LenstoolModel` or `~astropy.coordinates.SkyCoord`
        Origin of the model frame of the ``x`` and ``y`` columns (a model's
        ``origin``). A model also fills ``z_model``.

    Returns
    -------
    images : `~astropy.table.QTable`
        ``id``, ``system``, ``image`` (str: ``'4.1'`` is image ``'1'`` of
        system ``'4'``), ``sky`` (SkyCoord), ``x``, ``y`` (arcsec, model
        frame), ``a``, ``b`` (arcsec), ``theta`` (deg), ``z`` (NaN where the
        file has 0, i.e. unknown), ``mag`` (NaN if absent) and ``z_model``:
        ``z``, or where it is unknown the model's fitted redshift of the
        system (NaN when there is none or ``reference`` is a SkyCoord).
    """
    path = _as_path(path)
    if isinstance(reference, LenstoolModel):
        model = reference
        origin = reference.origin
    elif isinstance(reference, SkyCoord) and reference.isscalar:
        model = None
        origin = reference.icrs
    else:
        raise TypeError("reference must be a LenstoolModel or a scalar SkyCoord, got "
                        f"{type(reference).__name__}")
    cosd0 = math.cos(origin.dec.radian)
    file_ref = None  # None: absolute degrees; else the SkyCoord of a relative frame
    rows = []
    seen = {}
    lines = path.read_text(encoding="utf-8-sig", errors="replace").splitlines()
    for number, raw in enumerate(lines, start=1):
        text = raw.strip()
        where = f"{path}, line {number}"
        if not text:
            continue
        if text.startswith("#"):
            tokens = text[1:].split()
            if tokens and tokens[0].upper() == "REFERENCE":
                if rows:
                    raise ValueError(f"{where}: #REFERENCE must come before the images")
                file_ref = _catalogue_reference(tokens, text, where)
            continue
        tokens = text.split("#", 1)[0].split()
        if len(tokens) not in (7, 8):
            raise ValueError(f"{where}: expected 7 or 8 columns (id RA DEC a b theta z [mag]), "
                             f"got {len(tokens)}")
        ident = tokens[0]
        if ident in seen:
            raise ValueError(f"{where}: image {ident!r} already given at line {seen[ident]}")
        seen[ident] = number
        rows.append((ident, *_image_values(tokens, where), file_ref))
    if not rows:
        raise ValueError(f"{path}: no images")
    ident = [r[0] for r in rows]
    sky = _catalogue_sky(path, np.array([r[1] for r in rows]), np.array([r[2] for r in rows]),
                         rows[-1][-1])
    dra = (sky.ra.deg - origin.ra.deg + 180.0) % 360.0 - 180.0
    table = QTable()
    table["id"] = np.array(ident)
    split = [_split_image_id(i) for i in ident]
    table["system"] = np.array([s for s, _ in split])
    table["image"] = np.array([i for _, i in split])
    table["sky"] = sky
    table["x"] = -dra * cosd0 * 3600.0 * u.arcsec
    table["y"] = (sky.dec.deg - origin.dec.deg) * 3600.0 * u.arcsec
    table["a"] = np.array([r[3] for r in rows]) * u.arcsec
    table["b"] = np.array([r[4] for r in rows]) * u.arcsec
    table["theta"] = np.array([r[5] for r in rows]) * u.deg
    z = np.array([r[6] for r in rows])
    table["z"] = np.where(z > 0, z, np.nan)
    table["mag"] = np.array([r[7] for r in rows])
    fitted = model.fitted_redshifts if model is not None else {}
    table["z_model"] = np.array([
        zi if zi > 0 else fitted.get(sys, np.nan) for zi, sys in zip(z, table["system"],
                                                                       strict=True)])
    table.meta["path"] = str(path)
    table.meta["origin"] = origin
    return table

"""Constellations from multiple-image catalogues of knots (public in `lensdual.pairing`).

A published cluster model usually comes with a catalogue of multiple images:
one line per image, ``id RA Dec ...``, where the id ``K.n`` is image ``n`` of
system ``K``. When the systems ``K`` are the compact knots of one extended
galaxy that is itself imaged several times (the *macro-images*, e.g. the
spiral host of SN Refsdal in MACS J1149), the catalogue is a constellation: on
every pair of macro-images the knots seen in both give one pairs table.

Deciding which macro-image an image of a knot lies on is the delicate step:
the sub-index ``n`` is not reliable (catalogues number images in the order
they were found), extra images appear around cluster members, and two
macro-images of a fold can be only arcseconds apart. :func:`pairs_from_knots`
assigns images by the nearest macro-image centre, by a user mapping, or by a
lens model's counter-images, and reports every image it does not use and why.
"""

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from itertools import combinations

import numpy as np
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.table import QTable, Table

from ._frames import mean_direction, tangent_xy
from ._pairs_table import ID_COLUMNS, PAIR_ID, SKY_COLUMNS, flux_col, flux_err_col, xy_cols
from ._validation import as_angle_scalar, as_int, as_real

__all__ = ["KnotPairs", "pairs_from_knots", "read_macro_images"]

#: Status of an image in `KnotPairs.images`.
IMAGE_STATUS = {
    "used": "in at least one pairs table",
    "ambiguous": "its macro-image is not clear (two centres almost equally near, or "
                 "claimed by two macro-images of the model)",
    "extra": "a second image of its knot on the same macro-image (e.g. an extra image "
             "around a cluster member): the knot is left out of that macro-image",
    "unassigned": "on no macro-image (beyond max_distance, or the model maps no "
                  "macro-image onto it)",
    "single": "its knot is seen on only one macro-image",
    "inconsistent": "the model does not map it onto the source of its knot's other images "
                    "(a wrong identification, or the model fails there)",
}
#: Images closer than this are duplicates (a catalogue error).
_DUPLICATE = 1e-3 * u.arcsec
#: Centre assignment: an image is ambiguous when its nearest centre is farther
#: than this fraction of the distance to the second nearest.
_AMBIGUITY = 0.8
#: Model assignment: damped Newton steps (arcsec) and iterations.
_MAX_STEP = 0.5
_NEWTON_ITER = 60
#: Model assignment: an image is inconsistent with its knot's source beyond this
#: many times the median offset of all images (the model's own precision).
_CONSISTENCY = 5.0


@dataclass(frozen=True, repr=False)
class KnotPairs:
    """The constellations of a knot catalogue (made by :func:`pairs_from_knots`).

    Every parameter is also an attribute of the same name.

    Parameters
    ----------
    pairs : dict
        ``(macro1, macro2) -> pairs table`` (`~astropy.table.QTable`, see
        :ref:`pairs-table`) for each pair of macro-images, in the order of
        ``macro_images``. Arc L1 is ``macro1``, arc L2 ``macro2``.
    images : `~astropy.table.QTable`
        One row per knot image: ``id``, ``knot``, ``macro`` (the assigned
        macro-image, ``""`` when none), ``status`` (see ``IMAGE_STATUS``),
        ``distance`` (arcsec to the assigned or nearest centre), ``note``.
    macro_images : `~astropy.table.QTable`
        ``name``, ``sky``, ``x``, ``y`` (arcsec, common frame), ``n_knots``
        (knots with one clean image on it).
    reference : `~astropy.coordinates.SkyCoord`
        Tangent point of the ``x``, ``y`` columns (x West, y North).
    assign : str
        How images were assigned: ``"centre"``, ``"mapping"`` or ``"model"``.
    z_source : float
        Redshift of the knots (NaN when unknown and not needed).
    skipped : dict
        ``(macro1, macro2) -> reason`` for the pairs of macro-images that
        give no pairs table (too few common knots).

    Examples
    --------
    Three knots seen on macro-images A and B, and a fourth seen on A only:

    >>> import astropy.units as u
    >>> from astropy.coordinates import SkyCoord
    >>> from astropy.table import QTable
    >>> from lensdual.pairing import pairs_from_knots
    >>> c = SkyCoord(150 * u.deg, 2 * u.deg)
    >>> def at(dx, dy):  # arcsec West and North of c
    ...     return c.spherical_offsets_by(-dx * u.arcsec, dy * u.arcsec)
    >>> cat = QTable({"id": ["1.1", "1.2", "2.1", "2.2", "3.1", "3.2", "4.1"],
    ...               "sky": SkyCoord([at(-10, 0), at(10, 0), at(-9, 1), at(11, -1),
    ...                                at(-10.5, 1.5), at(9, 1), at(-9.5, -1)])})
    >>> kp = pairs_from_knots(cat, {"A": at(-10, 0.5), "B": at(10, 0)})
    >>> kp
    <KnotPairs of 7 images by centre: A-B: 3; 1 images not used>
    >>> print(kp.summary())
    7 knot images, assigned by centre
      A - B: 3 knots
      single (1): 4.1
    >>> kp["A", "B"]["id1"].tolist()
    ['1.1', '2.1', '3.1']
    """

    pairs: dict
    images: QTable
    macro_images: QTable
    reference: SkyCoord
    assign: str
    z_source: float = math.nan
    skipped: dict = field(default_factory=dict)

    def __repr__(self):
        tables = ", ".join(f"{a}-{b}: {len(t)}" for (a, b), t in self.pairs.items())
        return (f"<KnotPairs of {len(self.images)} images by {self.assign}: {tables}; "
                f"{len(self.dropped())} images not used>")

    def __getitem__(self, key):
        return self.pairs[tuple(key)]

    def __iter__(self):
        return iter(self.pairs)

    def __len__(self):
        return len(self.pairs)

    def dropped(self):
        """The images not used in any pairs table, with their status and note.

        Returns
        -------
        images : `~astropy.table.QTable`
            The rows of ``images`` whose status is not ``"used"``.
        """
        return self.images[self.images["status"] != "used"]

    def summary(self):
        """A short text report: pairs per macro-image pair and images left out.

        Returns
        -------
        text : str
        """
        lines = [f"{len(self.images)} knot images, assigned by {self.assign}"]
        for (m1, m2), tab in self.pairs.items():
            lines.append(f"  {m1} - {m2}: {len(tab)} knots")
        for key, why in self.skipped.items():
            lines.append(f"  {key[0]} - {key[1]}: no pairs table ({why})")
        for status in ("ambiguous", "extra", "inconsistent", "unassigned", "single"):
            sel = self.images["status"] == status
            if sel.any():
                ids = ", ".join(str(i) for i in self.images["id"][sel])
                lines.append(f"  {status} ({int(sel.sum())}): {ids}")
        return "\n".join(lines)


# ---------------------------------------------------------------------------
# input
# ---------------------------------------------------------------------------


def read_macro_images(path, names):
    r"""Macro-image centres from the commented lines of a Lenstool catalogue.

    Lenstool catalogues often keep images out of the fit by commenting them
    (``#1.1 177.39700 22.396007 ...``); the MACS J1149 knot catalogue gives
    the centres of the spiral's macro-images that way.

    Parameters
    ----------
    path : str or os.PathLike
        The catalogue (absolute RA and Dec in degrees).
    names : sequence of str
        The ids of the commented lines to read (e.g. ``["1.1", "1.2", "1.3"]``).

    Returns
    -------
    centres : dict
        ``name -> SkyCoord``, in the order of ``names``.

    Examples
    --------
    >>> import os
    >>> import tempfile
    >>> from lensdual.pairing import read_macro_images
    >>> tmp = tempfile.TemporaryDirectory()
    >>> path = os.path.join(tmp.name, "knots.cat")
    >>> with open(path, "w") as fh:
    ...     _ = fh.write("#REFERENCE 0\n"
    ...                  "#1.1 177.39700 22.396007 0.5 0.5 0 1.49 0\n"
    ...                  "#1.2 177.40000 22.398000 0.5 0.5 0 1.49 0\n"
    ...                  "2.1 177.39710 22.396100 0.1 0.1 0 1.49 0\n")
    >>> centres = read_macro_images(path, ["1.2", "1.1"])
    >>> list(centres)
    ['1.2', '1.1']
    >>> centres["1.2"].dec  # doctest: +FLOAT_CMP
    <Latitude 22.398 deg>
    >>> tmp.cleanup()
    """
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"path must be a str or os.PathLike, got {type(path).__name__}")
    names = [names] if isinstance(names, str) else [str(n) for n in names]
    found = {}
    with open(path, encoding="utf-8-sig", errors="replace") as fh:
        for number, raw in enumerate(fh, start=1):
            text = raw.strip()
            if not text.startswith("#"):
                continue
            tokens = text[1:].split()
            if len(tokens) >= 3 and tokens[0] in names and tokens[0] not in found:
                try:
                    ra, dec = float(tokens[1]), float(tokens[2])
                except ValueError:
                    raise ValueError(f"{path}, line {number}: cannot read RA and Dec of the "
                                     f"commented image {tokens[0]!r}") from None
                found[tokens[0]] = SkyCoord(ra * u.deg, dec * u.deg, frame="icrs")
    missing = [n for n in names if n not in found]
    if missing:
        raise ValueError(f"{path}: no commented line for the macro-image(s) {missing}")
    return {n: found[n] for n in names}


def _images_table(images, knots):
    """(ids, knots, sky, table) of the catalogue rows of the knot systems."""
    if isinstance(images, (str, os.PathLike)):
        from .parametric.lenstool import read_lenstool_images

        images = read_lenstool_images(images, reference=SkyCoord(0 * u.deg, 0 * u.deg))
    if not isinstance(images, Table):
        raise TypeError("images must be a catalogue path or an astropy Table with an 'id' "
                        f"column and sky positions, got {type(images).__name__}")
    tab = QTable(images)
    if "id" not in tab.colnames:
        raise ValueError(f"images needs an 'id' column (columns: {tab.colnames})")
    ids = np.array([str(i) for i in tab["id"]])
    if "sky" in tab.colnames and isinstance(tab["sky"], SkyCoord):
        sky = tab["sky"]
    elif "ra" in tab.colnames and "dec" in tab.colnames:
        ra, dec = tab["ra"], tab["dec"]
        ra = ra if isinstance(ra, u.Quantity) else np.asarray(ra, float) * u.deg
        dec = dec if isinstance(dec, u.Quantity) else np.asarray(dec, float) * u.deg
        sky = SkyCoord(ra, dec, frame="icrs")
    else:
        raise ValueError("images needs a SkyCoord column 'sky' or columns 'ra' and 'dec' "
                         f"(degrees); columns: {tab.colnames}")
    if "system" in tab.colnames:
        system = np.array([str(s) for s in tab["system"]])
    else:
        system = np.array([i.rsplit(".", 1)[0] if "." in i else i for i in ids])
    uniq, counts = np.unique(ids, return_counts=True)
    if (counts > 1).any():
        raise ValueError(f"images: the id(s) {uniq[counts > 1].tolist()} appear more than once")
    if knots is None:
        keep = np.ones(len(ids), bool)
    elif callable(knots):
        keep = np.array([bool(knots(s)) for s in system])
    else:
        wanted = [knots] if isinstance(knots, str) else [str(k) for k in knots]
        unknown = sorted(set(wanted) - set(system))
        if unknown:
            raise ValueError(f"knots: the system(s) {unknown} are not in the catalogue")
        keep = np.isin(system, wanted)
    if not keep.any():
        raise ValueError("knots selects no image of the catalogue")
    return ids[keep], system[keep], sky[keep], tab[keep]


def _macro_table(macro_images):
    """(names, SkyCoord) of the macro-image centres (dict, table or SkyCoord)."""
    if isinstance(macro_images, Mapping):
        names = [str(k) for k in macro_images]
        values = list(macro_images.values())
        if not all(isinstance(v, SkyCoord) and v.isscalar for v in values):
            raise TypeError("macro_images must map names to scalar SkyCoords")
        sky = SkyCoord(values)
    elif isinstance(macro_images, Table):
        col = "name" if "name" in macro_images.colnames else "id"
        if col not in macro_images.colnames or "sky" not in macro_images.colnames:
            raise ValueError("a macro_images table needs columns 'name' (or 'id') and 'sky'")
        names = [str(n) for n in macro_images[col]]
        sky = macro_images["sky"]
    elif isinstance(macro_images, (list, tuple)) and all(isinstance(n, str) for n in macro_images):
        names, sky = [str(n) for n in macro_images], None
    else:
        raise TypeError("macro_images must be a dict {name: SkyCoord}, a table with 'name' "
                        "and 'sky', or (with a mapping) a list of names; got "
                        f"{type(macro_images).__name__}")
    if len(names) < 2:
        raise ValueError(f"macro_images must name at least 2 macro-images, got {names}")
    if len(set(names)) != len(names):
        raise ValueError(f"macro_images has repeated names: {names}")
    return names, sky


def _check_duplicates(ids, xy):
    from scipy.spatial import cKDTree

    close = cKDTree(xy).query_pairs(_DUPLICATE.to_value(u.arcsec))
    if close:
        dup = sorted({(ids[i], ids[j]) for i, j in close})
        raise ValueError(f"images: duplicate images at the same position: {dup[:5]}")


# ---------------------------------------------------------------------------
# assignment
# ---------------------------------------------------------------------------


def _by_centre(xy, centres, max_distance, ambiguity):
    """Macro index per image (-1 none), status hint and distance to the nearest centre."""
    d = np.hypot(xy[:, None, 0] - centres[None, :, 0], xy[:, None, 1] - centres[None, :, 1])
    order = np.argsort(d, axis=1)
    nearest = order[:, 0]
    d1 = d[np.arange(len(xy)), nearest]
    d2 = d[np.arange(len(xy)), order[:, 1]]
    macro = nearest.copy()
    status = np.array([""] * len(xy), dtype=object)
    far = d1 > max_distance
    macro[far] = -1
    status[far] = "unassigned"
    amb = ~far & (d1 > ambiguity * d2)
    macro[amb] = -1
    status[amb] = "ambiguous"
    return macro, status, d1


def _by_mapping(ids, mapping, names):
    if isinstance(mapping, Table):
        if "id" not in mapping.colnames or "macro" not in mapping.colnames:
            raise ValueError("a mapping table needs columns 'id' and 'macro'")
        mapping = {str(i): str(m) for i, m in zip(mapping["id"], mapping["macro"], strict=True)}
    if not isinstance(mapping, Mapping):
        raise TypeError(f"mapping must be a dict {{image id: macro-image}} or a table, got "
                        f"{type(mapping).__name__}")
    mapping = {str(k): str(v) for k, v in mapping.items()}
    unknown = sorted(set(mapping) - set(ids))
    if unknown:
        raise ValueError(f"mapping: unknown image id(s) {unknown[:10]} (not among the knot "
                         "images)")
    bad = sorted({v for v in mapping.values() if v not in names})
    if bad:
        raise ValueError(f"mapping: unknown macro-image(s) {bad}; macro_images are {names}")
    index = {n: k for k, n in enumerate(names)}
    macro = np.array([index.get(mapping.get(i, ""), -1) for i in ids])
    status = np.where(macro < 0, "unassigned", "").astype(object)
    return macro, status


def _newton(lens, start, target):
    """Damped Newton solution of beta(theta) = target from ``start`` (arrays (M, 2))."""
    th = start.astype(float).copy()
    for _ in range(_NEWTON_ITER):
        bx, by = lens.ray_shooting(th[:, 0], th[:, 1])
        fxx, fxy, _, fyy = lens.hessian(th[:, 0], th[:, 1])
        a11, a12, a22 = 1 - np.asarray(fxx), -np.asarray(fxy), 1 - np.asarray(fyy)
        rx, ry = target[:, 0] - np.asarray(bx), target[:, 1] - np.asarray(by)
        det = a11 * a22 - a12 * a12
        with np.errstate(all="ignore"):
            dx = (a22 * rx - a12 * ry) / det
            dy = (-a12 * rx + a11 * ry) / det
        step = np.hypot(dx, dy)
        scale = np.where(step > _MAX_STEP, _MAX_STEP / np.where(step > 0, step, 1), 1.0)
        th[:, 0] += np.nan_to_num(dx * scale)
        th[:, 1] += np.nan_to_num(dy * scale)
        if np.all(step < 1e-9):
            break
    bx, by = lens.ray_shooting(th[:, 0], th[:, 1])
    miss = np.hypot(target[:, 0] - bx, target[:, 1] - by)
    th[~(miss < 1e-6)] = np.nan
    return th


def _by_model(sky, system, centres_sky, model, z_source, match_radius):
    """Macro index per image from a model's counter-images (see pairs_from_knots)."""
    lens = model.lens_model(z_source)
    xy = model.to_model_frame(sky).to_value(u.arcsec)
    c = model.to_model_frame(centres_sky).to_value(u.arcsec)
    bx, by = lens.ray_shooting(xy[:, 0], xy[:, 1])
    beta = np.column_stack([bx, by])
    n, m = len(xy), len(c)
    claims = np.zeros((n, m), bool)
    for k in range(m):
        sol = _newton(lens, np.repeat(c[k:k + 1], n, axis=0), beta)
        with np.errstate(invalid="ignore"):
            claims[:, k] = np.hypot(*(sol - xy).T) < match_radius
    macro = np.where(claims.sum(axis=1) == 1, np.argmax(claims, axis=1), -1)
    status = np.array([""] * n, dtype=object)
    status[claims.sum(axis=1) == 0] = "unassigned"
    status[claims.sum(axis=1) > 1] = "ambiguous"
    # every image of a knot must be an image of the knot's source (the median of
    # its images' sources): solve for it from the image itself
    target = np.empty_like(beta)
    for knot in np.unique(system):
        rows = system == knot
        target[rows] = np.median(beta[rows & (macro >= 0)] if (rows & (macro >= 0)).any()
                                 else beta[rows], axis=0)
    sol = _newton(lens, xy, target)
    offset = np.hypot(*(sol - xy).T)
    # the model reproduces a catalogue only to its own precision: an image is
    # inconsistent beyond _CONSISTENCY times the median offset (or match_radius)
    typical = np.nanmedian(offset[macro >= 0]) if (macro >= 0).any() else 0.0
    with np.errstate(invalid="ignore"):
        off = ~(offset < max(match_radius, _CONSISTENCY * typical))
    status[off & (macro >= 0)] = "inconsistent"
    macro[off] = -1
    return macro, status


def _knot_redshift(tab, z_source, needed):
    if z_source is not None:
        return as_real(z_source, "z_source", minimum=0.0, inclusive=False)
    for col in ("z", "z_model"):
        if col in tab.colnames:
            z = np.asarray(tab[col], float)
            z = z[np.isfinite(z) & (z > 0)]
            if len(z):
                if np.ptp(z) > 1e-6 * z.max():
                    raise ValueError(f"images: the knots have different redshifts "
                                     f"{sorted(set(z.tolist()))}; pass z_source")
                return float(z[0])
    if needed:
        raise ValueError("images: the knot system has no redshift (z column 0 or absent): pass "
                         "z_source to assign images with a model")
    return math.nan


# ---------------------------------------------------------------------------
# public function
# ---------------------------------------------------------------------------


def _check_assign(assign, mapping, model, centres_sky):
    """The assignment method (default from the arguments given), checked."""
    if assign is None:
        assign = "mapping" if mapping is not None else "model" if model is not None else "centre"
    if assign not in ("centre", "mapping", "model"):
        raise ValueError(f"assign must be 'centre', 'mapping' or 'model', got {assign!r}")
    if assign == "mapping" and mapping is None:
        raise ValueError("assign='mapping' needs a mapping {image id: macro-image}")
    if assign == "model" and model is None:
        raise ValueError("assign='model' needs a model (e.g. read_lenstool(...))")
    if centres_sky is None and assign != "mapping":
        raise ValueError("macro_images given as names only: give their centres (dict {name: "
                         "SkyCoord}) or assign with a mapping")
    return assign


def _crowds(system, macro, status, names):
    """Mark "extra" and "single" images in ``status``; their notes, and the used images.

    A knot with two images on one macro-image: both are "extra" there (the knot
    is not used on that macro-image); a knot on one macro-image only: "single".
    """
    note = np.array([""] * len(system), dtype=object)
    for knot in np.unique(system):
        rows = np.flatnonzero((system == knot) & (macro >= 0))
        on, counts = np.unique(macro[rows], return_counts=True)
        for k in on[counts > 1]:
            crowd = rows[macro[rows] == k]
            status[crowd] = "extra"
            note[crowd] = f"{len(crowd)} images of knot {knot} on {names[k]}"
        clean = on[counts == 1]
        if len(clean) < 2:
            lone = rows[np.isin(macro[rows], clean)]
            status[lone] = "single"
            note[lone] = f"knot {knot} seen cleanly on {len(clean)} macro-image(s)"
    used = (status == "") & (macro >= 0)
    status[used] = "used"
    return note, used


def _knot_table(common, i, j, ids, xy, sky, tab, bands, flux_columns, flux_err_columns):
    """The pairs table of the knots ``common`` at rows i (macro1) and j (macro2)."""
    out = QTable()
    out[PAIR_ID] = np.arange(1, len(common) + 1)
    out["knot"] = np.array(common)
    out[ID_COLUMNS[0]], out[ID_COLUMNS[1]] = ids[i], ids[j]
    for (x, y), rows in ((xy_cols(1), i), (xy_cols(2), j)):
        out[x], out[y] = xy[rows, 0] * u.arcsec, xy[rows, 1] * u.arcsec
    out[SKY_COLUMNS[0]], out[SKY_COLUMNS[1]] = sky[i], sky[j]
    for band in ([] if bands is None else [bands] if isinstance(bands, str) else bands):
        fcol, ecol = flux_columns.format(band=band), flux_err_columns.format(band=band)
        if fcol not in tab.colnames:
            raise ValueError(f"images has no flux column {fcol!r} of band {band!r}")
        out[flux_col(1, band)], out[flux_col(2, band)] = tab[fcol][i], tab[fcol][j]
        if ecol in tab.colnames:
            out[flux_err_col(1, band)], out[flux_err_col(2, band)] = tab[ecol][i], tab[ecol][j]
    return out


def _report_tables(ids, system, macro, status, nearest, note, names, centres_sky, cxy, n_knots):
    """The ``images`` and ``macro_images`` tables of `KnotPairs`."""
    report = QTable()
    report["id"] = ids
    report["knot"] = system
    report["macro"] = np.array([names[k] if k >= 0 else "" for k in macro])
    report["status"] = status.astype(str)
    report["distance"] = nearest * u.arcsec
    report["note"] = note.astype(str)
    macro_tab = QTable()
    macro_tab["name"] = np.array(names)
    if centres_sky is not None:
        macro_tab["sky"] = centres_sky
        macro_tab["x"], macro_tab["y"] = cxy[:, 0] * u.arcsec, cxy[:, 1] * u.arcsec
    macro_tab["n_knots"] = n_knots
    return report, macro_tab


def pairs_from_knots(images, macro_images, *, knots=None, assign=None, mapping=None, model=None,
                     z_source=None, reference=None, max_distance=None, match_radius=0.3 * u.arcsec,
                     min_knots=3, bands=None, flux_columns="flux_{band}",
                     flux_err_columns="flux_err_{band}"):
    """Pairs tables of a knot constellation, one per pair of macro-images.

    Parameters
    ----------
    images : str, os.PathLike or `~astropy.table.Table`
        The multiple-image catalogue: a Lenstool catalogue file (``.mul``,
        ``arcs.dat``; read with
        :func:`~lensdual.parametric.read_lenstool_images`) or a table with an
        ``id`` column and a SkyCoord column ``sky`` (or ``ra`` and ``dec`` in
        degrees). The knot of an image is its ``system`` column, else the id
        up to its last dot (``"1002.3"`` is an image of knot ``"1002"``).
    macro_images : dict, `~astropy.table.Table` or list of str
        The macro-images: ``{name: SkyCoord centre}`` (e.g. from
        :func:`read_macro_images`), a table with ``name`` and ``sky``, or,
        with a ``mapping``, just their names.
    knots : sequence of str or callable, optional
        The systems that are knots (default: every row). A callable takes a
        system name and returns True for a knot, e.g. ``lambda s: 1000 <=
        int(s) < 2000``.
    assign : {"centre", "mapping", "model"}, optional
        How to assign an image to a macro-image. ``"centre"``: the nearest
        centre, within ``max_distance``; an image whose two nearest centres
        are almost equally far (ratio above 0.8) is ambiguous. ``"mapping"``:
        ``mapping`` says it. ``"model"``: each image is traced to the source
        plane with ``model`` and the lens equation is solved from every
        macro-image centre (damped Newton); the macro-images whose solution
        lands within ``match_radius`` of the image claim it; claimed by none:
        unassigned, by several: ambiguous. An image the model does not map
        onto its knot's source (the median source of the knot's images)
        within ``match_radius`` or 5 times the median such offset of the
        catalogue (the model's own precision), whichever is larger, is
        inconsistent. Default: ``"mapping"`` with a
        mapping, else ``"model"`` with a model, else ``"centre"``.
    mapping : dict or `~astropy.table.Table`, optional
        ``{image id: macro-image name}`` (or a table with ``id`` and
        ``macro``); images it does not name are unassigned.
    model : `~lensdual.parametric.LenstoolModel`, optional
        A lens model (anything with ``to_model_frame(sky)`` and
        ``lens_model(z_source)`` returning an object with ``ray_shooting``
        and ``hessian``).
    z_source : float, optional
        Redshift of the knots; default the catalogue's ``z`` (or ``z_model``).
        Needed only with a model.
    reference : `~astropy.coordinates.SkyCoord`, optional
        Tangent point of the ``x``, ``y`` columns; default the mean direction
        of the knot images.
    max_distance : `~astropy.units.Quantity`, optional
        Centre assignment: images farther than this from every centre are
        unassigned (default: no limit).
    match_radius : `~astropy.units.Quantity`
        Model assignment: how close a predicted counter-image must land
        (default 0.3 arcsec, a few times the scatter of a good cluster model).
    min_knots : int
        Fewest knots a macro-image needs (default 3, the fewest that give a
        relative Jacobian); a macro-image with fewer is an error.
    bands : sequence of str, optional
        Bands whose fluxes are copied into the pairs tables (columns
        ``flux_columns`` and, when present, ``flux_err_columns`` formatted
        with ``band``). Default: none (position-only pairs tables).
    flux_columns, flux_err_columns : str
        Catalogue column names of the flux and its error, with a ``{band}``
        field (default ``"flux_{band}"`` and ``"flux_err_{band}"``).

    Returns
    -------
    knot_pairs : `KnotPairs`
        ``knot_pairs.pairs[(m1, m2)]`` is the pairs table of macro-images
        ``m1`` (arc L1) and ``m2`` (arc L2): ``pair_id``, ``knot``, ``id1``,
        ``id2``, ``x1``, ``y1``, ``x2``, ``y2`` (arcsec, x West, about
        ``knot_pairs.reference``), ``sky1``, ``sky2`` and any fluxes; its
        ``meta`` holds ``macro1``, ``macro2``, ``reference``, ``bands`` and
        ``z_source``. ``knot_pairs.images`` says for every image where it
        went and, when it is not used, why (``knot_pairs.summary()``).

    Raises
    ------
    ValueError
        Unknown ids or macro-images in ``mapping``, duplicate images, a
        macro-image with fewer than ``min_knots`` knots, no redshift for a
        model assignment.

    Examples
    --------
    >>> import astropy.units as u
    >>> from astropy.coordinates import SkyCoord
    >>> from astropy.table import QTable
    >>> from lensdual.pairing import pairs_from_knots
    >>> c = SkyCoord(150 * u.deg, 2 * u.deg)
    >>> def at(dx, dy):  # arcsec West and North of c
    ...     return c.spherical_offsets_by(-dx * u.arcsec, dy * u.arcsec)
    >>> cat = QTable({"id": ["1.1", "1.2", "2.1", "2.2", "3.1", "3.2"],
    ...               "sky": SkyCoord([at(-10, 0), at(10, 0), at(-9, 1), at(11, -1),
    ...                                at(-10.5, 1.5), at(9, 1)])})
    >>> kp = pairs_from_knots(cat, {"A": at(-10, 0.5), "B": at(10, 0)})
    >>> list(kp.pairs), len(kp[("A", "B")])
    ([('A', 'B')], 3)
    """
    ids, system, sky, tab = _images_table(images, knots)
    names, centres_sky = _macro_table(macro_images)
    assign = _check_assign(assign, mapping, model, centres_sky)
    min_knots = as_int(min_knots, "min_knots", minimum=3)
    z_source = _knot_redshift(tab, z_source, needed=assign == "model")
    if reference is None:
        reference = mean_direction(sky)
    elif not (isinstance(reference, SkyCoord) and reference.isscalar):
        raise TypeError(f"reference must be a scalar SkyCoord, got {reference!r}")
    xy = np.column_stack(tangent_xy(sky, reference))
    _check_duplicates(ids, xy)

    nearest = np.full(len(ids), np.nan)
    cxy = None
    if centres_sky is not None:
        cxy = np.column_stack(tangent_xy(centres_sky, reference))
        _, _, nearest = _by_centre(xy, cxy, np.inf, 1.0)
    if assign == "centre":
        limit = np.inf if max_distance is None else as_angle_scalar(
            max_distance, "max_distance", allow_zero=False)
        macro, status, _ = _by_centre(xy, cxy, limit, _AMBIGUITY)
    elif assign == "mapping":
        macro, status = _by_mapping(ids, mapping, names)
    else:
        radius = as_angle_scalar(match_radius, "match_radius", allow_zero=False)
        macro, status = _by_model(sky, system, centres_sky, model, z_source, radius)
    note, used = _crowds(system, macro, status, names)

    n_knots = np.array([int(np.sum(used & (macro == k))) for k in range(len(names))])
    few = [f"{names[k]} ({n_knots[k]})" for k in range(len(names)) if n_knots[k] < min_knots]
    if few:
        raise ValueError(f"macro_images: {', '.join(few)} have fewer than {min_knots} knots with "
                         f"one clean image (assign={assign!r}); check the centres or mapping, "
                         "or leave those macro-images out")

    pairs, skipped = {}, {}
    for a, b in combinations(range(len(names)), 2):
        common = sorted(set(system[used & (macro == a)]) & set(system[used & (macro == b)]))
        if len(common) < min_knots:
            skipped[(names[a], names[b])] = f"{len(common)} common knots < {min_knots}"
            continue
        i = np.array([np.flatnonzero(used & (macro == a) & (system == k))[0] for k in common])
        j = np.array([np.flatnonzero(used & (macro == b) & (system == k))[0] for k in common])
        out = _knot_table(common, i, j, ids, xy, sky, tab, bands, flux_columns,
                          flux_err_columns)
        out.meta.update(bands=[] if bands is None else list(np.atleast_1d(bands)),
                        reference=reference, macro1=names[a], macro2=names[b],
                        z_source=z_source, assign=assign)
        pairs[(names[a], names[b])] = out

    report, macro_tab = _report_tables(ids, system, macro, status, nearest, note, names,
                                       centres_sky, cxy, n_knots)
    return KnotPairs(pairs=pairs, images=report, macro_images=macro_tab, reference=reference,
                     assign=assign, z_source=z_source, skipped=skipped)

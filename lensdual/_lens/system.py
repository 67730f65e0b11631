"""A lens system: lenstronomy profiles, redshifts and a cosmology, with units."""

import warnings

import numpy as np
from astropy import units as u
from astropy.table import QTable

from .._pairs_table import ARCS, PAIR_ID, flux_col, flux_err_col, xy_cols
from .._validation import as_cosmology, as_positions, as_real, as_redshifts
from ..exceptions import LensdualWarning
from .component import LensComponent

__all__ = ["LensSystem"]


def _lenstronomy_param_names(profile):
    """Required and optional keyword names of a lenstronomy profile."""
    from lenstronomy.LensModel.lens_model import LensModel

    func = LensModel([profile]).lens_model.func_list[0]
    lower = getattr(func, "lower_limit_default", {}) or {}
    names = list(getattr(func, "param_names", lower.keys()))
    return names


class LensSystem:
    """A single-plane lens: lenstronomy profiles, redshifts and a cosmology.

    Parameters
    ----------
    components : list of `~lensdual.simulation.LensComponent`
        The lens profiles (main halo, members, sub-haloes, ...). Their
        keyword arguments are checked against the lenstronomy profile now,
        not at the first deflection.
    z_lens, z_source : float
        Redshifts, ``z_source > z_lens``.
    cosmology : `~astropy.cosmology.Cosmology`, optional
        Defaults to flat LambdaCDM with H0 = 70, Om0 = 0.3.
    sources : `~astropy.units.Quantity`, shape (M, 2), optional
        Source-plane positions of a point-source constellation, the default
        of :meth:`constellation`.

    Notes
    -----
    Positions are (N, 2) angle Quantities in the lens frame (arcsec, x and y
    as in lenstronomy). ``jacobian`` is ``d beta / d theta`` (the inverse
    magnification matrix); ``magnification`` is signed, ``1 / det``.
    """

    def __init__(self, components, *, z_lens, z_source, cosmology=None, sources=None):
        from lenstronomy.LensModel.lens_model import LensModel

        self.z_lens, self.z_source = as_redshifts(z_lens, z_source)
        self.cosmology = as_cosmology(cosmology)
        components = list(components)
        if not components:
            raise ValueError("a LensSystem needs at least one component")
        for i, comp in enumerate(components):
            if not isinstance(comp, LensComponent):
                raise TypeError(f"component {i} must be a LensComponent, got "
                                f"{type(comp).__name__}")
            self._check_component(i, comp)
        self.components = tuple(components)
        self.label = "lenstronomy model"
        self.lens_model = LensModel([c.profile for c in components])
        self.kwargs_lens = [dict(c.kwargs) for c in components]
        self.sources = None if sources is None else as_positions(sources, "sources") * u.arcsec
        self._finders = {}

    @staticmethod
    def _check_component(i, comp):
        try:
            names = _lenstronomy_param_names(comp.profile)
        except Exception as exc:  # lenstronomy raises ValueError for unknown names
            raise ValueError(f"component {i} ({comp.label!r}): unknown lenstronomy profile "
                             f"{comp.profile!r}") from exc
        unknown = sorted(set(comp.kwargs) - set(names))
        missing = sorted(set(names) - set(comp.kwargs))
        if unknown or missing:
            raise ValueError(f"component {i} ({comp.label!r}, {comp.profile}): "
                             f"missing keyword(s) {missing}, unknown keyword(s) {unknown}")
        bad = [k for k, v in comp.kwargs.items() if not np.all(np.isfinite(v))]
        if bad:
            raise ValueError(f"component {i} ({comp.label!r}): non-finite value of {bad}")

    # ------------------------------------------------------------------ building

    @classmethod
    def from_model(cls, model, kwargs_lens=None, *, z_lens, z_source, cosmology=None,
                   sources=None, label="custom model"):
        """A system around any object with lenstronomy's ``LensModel`` interface.

        ``model`` must provide ``ray_shooting(x, y, kwargs)``,
        ``alpha(x, y, kwargs)`` and ``hessian(x, y, kwargs)`` on float arrays
        in arcsec (e.g. a lenstronomy ``LensModel``, or the Numba dPIE model
        of a Lenstool file); ``kwargs_lens`` is passed through unchanged.
        Such a system has no components, so :meth:`add` is not available.

        Parameters
        ----------
        model : object
            The lens model (``ray_shooting``, ``alpha``, ``hessian``).
        kwargs_lens : object, optional
            Its keyword arguments, passed to every call.
        z_lens, z_source : float
            Redshifts (``z_source > z_lens``).
        cosmology : `~astropy.cosmology.Cosmology`, optional
            Defaults to :data:`DEFAULT_COSMOLOGY`.
        sources : `~astropy.units.Quantity`, shape (M, 2), optional
            Source positions attached to the system.
        label : str
            A name for the model.

        Returns
        -------
        system : `LensSystem`
        """
        for name in ("ray_shooting", "alpha", "hessian"):
            if not callable(getattr(model, name, None)):
                raise TypeError(f"model must have a {name}(x, y, kwargs) method like "
                                f"lenstronomy's LensModel; {type(model).__name__} has none")
        self = cls.__new__(cls)
        self.z_lens, self.z_source = as_redshifts(z_lens, z_source)
        self.cosmology = as_cosmology(cosmology)
        self.components = ()
        self.label = label
        self.lens_model = model
        self.kwargs_lens = kwargs_lens
        self.sources = None if sources is None else as_positions(sources, "sources") * u.arcsec
        self._finders = {}
        return self

    def add(self, *components):
        """A new system with ``components`` appended (this one is unchanged).

        Parameters
        ----------
        *components : `LensComponent`
            The components to add.

        Returns
        -------
        system : `LensSystem`
        """
        if not self.components:
            raise TypeError("add() needs a system built from LensComponents; this one wraps "
                            f"a {type(self.lens_model).__name__}")
        return LensSystem(self.components + tuple(components), z_lens=self.z_lens,
                          z_source=self.z_source, cosmology=self.cosmology, sources=self.sources)

    def __repr__(self):
        parts = ", ".join(f"{c.label or c.profile}" for c in self.components) or self.label
        return (f"<LensSystem z_lens={self.z_lens} z_source={self.z_source} "
                f"components=[{parts}]>")

    # ------------------------------------------------------------------ lensing

    def _xy(self, theta, name="theta"):
        arr = as_positions(theta, name)
        return arr[:, 0], arr[:, 1]

    def ray_shoot(self, theta):
        """Source-plane positions ``beta = theta - alpha(theta)``.

        Parameters
        ----------
        theta : `~astropy.units.Quantity`, shape (N, 2)
            Image-plane positions (angles, lens frame).

        Returns
        -------
        beta : `~astropy.units.Quantity`, shape (N, 2)
            Arcsec.
        """
        x, y = self._xy(theta)
        bx, by = self.lens_model.ray_shooting(x, y, self.kwargs_lens)
        return np.column_stack([bx, by]) * u.arcsec

    def deflection(self, theta):
        """Deflection angles ``alpha(theta)``.

        Parameters
        ----------
        theta : `~astropy.units.Quantity`, shape (N, 2)
            Image-plane positions (angles, lens frame).

        Returns
        -------
        alpha : `~astropy.units.Quantity`, shape (N, 2)
            Arcsec.
        """
        x, y = self._xy(theta)
        ax, ay = self.lens_model.alpha(x, y, self.kwargs_lens)
        return np.column_stack([ax, ay]) * u.arcsec

    def _jacobian_xy(self, x, y):
        fxx, fxy, fyx, fyy = self.lens_model.hessian(x, y, self.kwargs_lens)
        jac = np.empty((np.size(x), 2, 2))
        jac[:, 0, 0] = 1 - fxx
        jac[:, 0, 1] = -fxy
        jac[:, 1, 0] = -fyx
        jac[:, 1, 1] = 1 - fyy
        return jac

    def jacobian(self, theta):
        """Lens Jacobian ``d beta / d theta`` at ``theta``.

        Parameters
        ----------
        theta : `~astropy.units.Quantity`, shape (N, 2)
            Image-plane positions (angles, lens frame).

        Returns
        -------
        jacobian : `~numpy.ndarray`, shape (N, 2, 2)
        """
        return self._jacobian_xy(*self._xy(theta))

    def magnification(self, theta):
        """Signed magnification ``1 / det(d beta / d theta)``.

        Parameters
        ----------
        theta : `~astropy.units.Quantity`, shape (N, 2)
            Image-plane positions (angles, lens frame).

        Returns
        -------
        magnification : `~numpy.ndarray`, shape (N,)
        """
        jac = self.jacobian(theta)
        with np.errstate(divide="ignore"):
            return 1.0 / np.linalg.det(jac)

    # ------------------------------------------------------------------ curves

    def _det_grid(self, center, half_width, grid_spacing):
        c = np.asarray(u.Quantity(center, u.arcsec).value, dtype=float)
        hw = as_real(u.Quantity(half_width, u.arcsec).value, "half_width", minimum=0.0,
                     inclusive=False)
        h = as_real(u.Quantity(grid_spacing, u.arcsec).value, "grid_spacing", minimum=0.0,
                    inclusive=False)
        n = int(np.ceil(2 * hw / h)) + 1
        if n * n > 2e7:
            raise ValueError(f"critical-curve grid of {n} x {n} points is too large; "
                             "increase grid_spacing or reduce half_width")
        xs = c[0] + np.linspace(-hw, hw, n)
        ys = c[1] + np.linspace(-hw, hw, n)
        xx, yy = np.meshgrid(xs, ys)
        det = np.linalg.det(self._jacobian_xy(xx.ravel(), yy.ravel())).reshape(xx.shape)
        return xs, ys, det

    def critical_curves(self, *, center=(0.0, 0.0) * u.arcsec, half_width=30 * u.arcsec,
                        grid_spacing=0.05 * u.arcsec):
        """Critical curves (``det d beta / d theta = 0``) traced on a grid.

        The zero contour of the Jacobian determinant on a regular grid
        (contourpy's marching squares, linear interpolation between nodes),
        so the curves are accurate to a small fraction of ``grid_spacing``.

        Parameters
        ----------
        center : `~astropy.units.Quantity`, shape (2,)
            Centre of the grid (default the origin).
        half_width : `~astropy.units.Quantity`
            Half the side of the square grid (default 30 arcsec).
        grid_spacing : `~astropy.units.Quantity`
            Grid step (default 0.05 arcsec).

        Returns
        -------
        curves : list of `~astropy.units.Quantity`
            One (K, 2) array per curve, arcsec. Closed curves repeat their
            first point at the end; a curve that leaves the grid is open.
        """
        import contourpy

        xs, ys, det = self._det_grid(center, half_width, grid_spacing)
        gen = contourpy.contour_generator(xs, ys, det, line_type="Separate")
        return [np.asarray(line) * u.arcsec for line in gen.lines(0.0) if len(line) > 1]

    def caustics(self, **kwargs):
        """Caustics: the critical curves mapped to the source plane.

        Parameters
        ----------
        **kwargs
            The arguments of :meth:`critical_curves`.

        Returns
        -------
        caustics : list of `~astropy.units.Quantity`
            One (K, 2) array per critical curve, arcsec.
        """
        return [self.ray_shoot(c) for c in self.critical_curves(**kwargs)]

    # ------------------------------------------------------------------ images

    def image_finder(self, *, center=(0.0, 0.0) * u.arcsec, half_width=50 * u.arcsec,
                     grid_spacing=0.5 * u.arcsec, refine=5):
        """The (cached) image finder for one image-plane grid.

        The base grid of ``grid_spacing`` is subdivided ``refine`` times per
        side around critical curves and lens centres, and recursively where
        the Jacobian varies strongly (see ``lensdual._lens._solver``).

        Parameters
        ----------
        center : `~astropy.units.Quantity`, shape (2,)
            Centre of the image-plane grid (default the origin).
        half_width : `~astropy.units.Quantity`
            Half the side of the grid (default 50 arcsec).
        grid_spacing : `~astropy.units.Quantity`
            Base grid step (default 0.5 arcsec).
        refine : int
            Subdivisions per side near critical curves and lens centres.

        Returns
        -------
        finder : ``ImageFinder``
            Built once per grid and cached on the system.
        """
        from ._solver import ImageFinder

        c = tuple(float(v) for v in u.Quantity(center, u.arcsec).value)
        hw = float(u.Quantity(half_width, u.arcsec).value)
        h = float(u.Quantity(grid_spacing, u.arcsec).value)
        key = (c, hw, h, refine)
        if key not in self._finders:
            self._finders[key] = ImageFinder(self.lens_model, self.kwargs_lens, center=c,
                                             half_width=hw, grid_spacing=h, refine=refine)
        return self._finders[key]

    def solve_images(self, beta, *, center=(0.0, 0.0) * u.arcsec, half_width=50 * u.arcsec,
                     grid_spacing=0.5 * u.arcsec, refine=5, link_length=2.0 * u.arcsec):
        """All images of the point sources at ``beta``.

        The image plane (``center`` +- ``half_width``) is traced on a grid of
        ``grid_spacing`` (refined ``refine`` times per side near critical
        curves and lens centres), split by the sign of the Jacobian determinant and
        inverted triangle by triangle; every candidate is then refined by
        Newton's method with the analytic Jacobian to 1e-8 arcsec in the
        source plane (paper App. A). The grid is built once per system and
        grid and reused.

        Parameters
        ----------
        beta : `~astropy.units.Quantity`, shape (M, 2)
            Source positions.
        center, half_width, grid_spacing, refine
            The image-plane grid, see :meth:`image_finder`.
        link_length : `~astropy.units.Quantity`
            Images of the same parity closer than this (over all sources)
            are given the same ``arc`` label (single linkage).

        Returns
        -------
        images : `~astropy.table.QTable`
            One row per image: ``source`` (row of ``beta``), ``x``, ``y``
            (arcsec), ``magnification`` (signed), ``parity`` (+1/-1) and
            ``arc`` (an integer label: arcs are numbered from 0 by decreasing
            number of images, then by decreasing median ``|magnification|``).
        """
        b = as_positions(beta, "beta")
        link = float(u.Quantity(link_length, u.arcsec).value)
        res = self.image_finder(center=center, half_width=half_width,
                                grid_spacing=grid_spacing, refine=refine).solve(b)
        theta = res["theta"]
        mu = res["magnification"]
        parity = np.sign(mu).astype(int)
        arc = _link_arcs(theta, parity, link)
        # renumber arcs: most images first, then most magnified
        labels = np.unique(arc)
        counts = np.array([np.sum(arc == k) for k in labels])
        med = np.array([np.median(np.abs(mu[arc == k])) for k in labels])
        order = labels[np.lexsort((-med, -counts))]
        remap = np.empty(labels.max() + 1 if labels.size else 0, dtype=int)
        remap[order] = np.arange(order.size)
        tab = QTable()
        tab["source"] = res["source"].astype(int)
        tab["x"] = theta[:, 0] * u.arcsec
        tab["y"] = theta[:, 1] * u.arcsec
        tab["magnification"] = mu
        tab["parity"] = parity
        tab["arc"] = remap[arc] if arc.size else arc
        tab.meta["n_sources"] = len(b)
        return tab

    def constellation(self, beta=None, *, bands=("F150W", "F200W"), intrinsic_flux=None,
                      flux_unit=u.nJy, flux_rel_err=0.02, add_flux_noise=False, seed=None,
                      merge_radius=0.05 * u.arcsec, reference=None, **solve_kwargs):
        """The pairs table of the fold pair of arcs for a constellation of point sources.

        The two arcs are the pair of opposite-parity arcs that hold an image
        of the most sources (ties broken by the larger magnification); arc
        L1 is the positive-parity one, so a fold pair has parity -1 from L2
        to L1. Sources without an image on both arcs are left out with a
        warning.

        Parameters
        ----------
        beta : `~astropy.units.Quantity`, shape (M, 2)
            Source positions of the constellation.
        bands : sequence of str
            Band names of the flux columns.
        intrinsic_flux : dict or None
            Unlensed flux per band, arrays of shape (M,). ``None`` draws them
            log-uniformly between 1 and 10 (``flux_unit``), with one random
            colour per source shared by both arcs.
        flux_unit : `~astropy.units.UnitBase`
            Unit of the fluxes.
        flux_rel_err : float
            Relative flux error written to the ``flux_err`` columns (> 0).
        add_flux_noise : bool
            Scatter the fluxes by their errors (Gaussian); otherwise the fluxes
            are exactly ``|mu| x intrinsic``.
        seed : int, `numpy.random.Generator` or None
            Seed of the random fluxes and noise.
        merge_radius : `~astropy.units.Quantity`
            Images closer than this count as one (default 0.05 arcsec).
        reference : `~astropy.units.Quantity`, shape (2, 2), optional
            Image-plane positions near arc L1 (row 0) and arc L2 (row 1):
            the arcs holding the images nearest to them are used instead of
            the automatic choice of the fold pair (for example a pair of arcs
            next to a cusp). Row 0 must point at a positive-parity arc.
        **solve_kwargs
            Passed to :meth:`solve_images`.

        Returns
        -------
        pairs : `~astropy.table.QTable`
            The pairs table, plus ``source`` (row of ``beta``), ``beta_x``,
            ``beta_y``, the true signed magnifications ``mu1`` and ``mu2``
            (summed over merged micro-images), ``n_images1`` and ``n_images2``
            (images merged into each) and ``mu_true = |mu1 / mu2|``.
            ``meta['bands']`` lists the bands.
        """
        if beta is None:
            if self.sources is None:
                raise ValueError("no source positions: pass beta or build the system with "
                                 "sources=...")
            beta = self.sources
        b = as_positions(beta, "beta")
        merge = float(u.Quantity(merge_radius, u.arcsec).value)
        m = len(b)
        rng = np.random.default_rng(seed)
        rel = as_real(flux_rel_err, "flux_rel_err", minimum=0.0, inclusive=False)
        bands = [bands] if isinstance(bands, str) else list(bands)
        if not bands:
            raise ValueError("bands must name at least one band")
        if intrinsic_flux is None:
            base = 10 ** rng.uniform(0.0, 1.0, m)
            colour = 10 ** rng.uniform(-0.2, 0.2, (len(bands), m))
            intrinsic_flux = {band: base * colour[i] for i, band in enumerate(bands)}
        missing = [band for band in bands if band not in intrinsic_flux]
        if missing:
            raise ValueError(f"intrinsic_flux lacks band(s) {missing}")

        images = self.solve_images(b * u.arcsec, **solve_kwargs)
        if reference is None:
            arc1, arc2 = _fold_arcs(images, m)
        else:
            arc1, arc2 = reference_arcs(images, reference)
        rows = {label: _merge_images(images[images["arc"] == label], merge)
                for label in (arc1, arc2)}
        common = sorted(set(rows[arc1]) & set(rows[arc2]))
        dropped = sorted(set(range(m)) - set(common))
        if dropped:
            warnings.warn(f"source(s) {dropped} have no image on one of the two fold arcs and "
                          "are left out of the constellation", LensdualWarning, stacklevel=2)
        if len(common) < 3:
            raise ValueError(f"only {len(common)} source(s) are imaged on both fold arcs; a "
                             "constellation needs at least 3")
        r1 = np.array([rows[arc1][s] for s in common])
        r2 = np.array([rows[arc2][s] for s in common])
        pairs = QTable()
        pairs[PAIR_ID] = np.arange(1, len(common) + 1)
        pairs["source"] = np.array(common)
        for (x, y), r in ((xy_cols(1), r1), (xy_cols(2), r2)):
            pairs[x], pairs[y] = r[:, 0] * u.arcsec, r[:, 1] * u.arcsec
        pairs["beta_x"] = b[common, 0] * u.arcsec
        pairs["beta_y"] = b[common, 1] * u.arcsec
        mu1, mu2 = r1[:, 2], r2[:, 2]
        pairs["mu1"] = mu1
        pairs["mu2"] = mu2
        pairs["n_images1"] = r1[:, 3].astype(int)
        pairs["n_images2"] = r2[:, 3].astype(int)
        pairs["mu_true"] = np.abs(mu1 / mu2)
        for band in bands:
            f0 = np.asarray(intrinsic_flux[band], dtype=float)
            if f0.shape != (m,) or not (np.isfinite(f0).all() and (f0 > 0).all()):
                raise ValueError(f"intrinsic_flux[{band!r}] must hold {m} positive fluxes")
            for arc, mu in zip(ARCS, (mu1, mu2), strict=True):
                flux = np.abs(mu) * f0[common]
                err = rel * flux
                if add_flux_noise:
                    flux = flux + err * rng.standard_normal(flux.size)
                pairs[flux_col(arc, band)] = flux * flux_unit
                pairs[flux_err_col(arc, band)] = err * flux_unit
        pairs.meta["bands"] = bands
        pairs.meta["frame"] = "lens-centred image plane, arcsec (lenstronomy x, y)"
        pairs.meta["arcs"] = {"L1": int(arc1), "L2": int(arc2)}
        return pairs


def _merge_images(images, merge):
    """Per source: (x, y, signed mu, n_images) of its images on one arc, merged.

    Images within ``merge`` of the source's most magnified image are one
    unresolved image: ``|mu|`` adds up, the position is the ``|mu|``-weighted
    mean and the sign is that of the most magnified image.
    """
    out = {}
    src = np.asarray(images["source"])
    xy = np.column_stack([images["x"].to_value(u.arcsec), images["y"].to_value(u.arcsec)])
    mu = np.asarray(images["magnification"], dtype=float)
    for s in np.unique(src):
        idx = np.flatnonzero(src == s)
        top = idx[np.argmax(np.abs(mu[idx]))]
        near = idx[np.hypot(*(xy[idx] - xy[top]).T) <= merge]
        w = np.abs(mu[near])
        pos = (w[:, None] * xy[near]).sum(axis=0) / w.sum()
        out[int(s)] = (pos[0], pos[1], np.sign(mu[top]) * w.sum(), near.size)
    return out


def _link_arcs(theta, parity, link):
    """Single-linkage labels of images of equal parity closer than ``link``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = len(theta)
    if n == 0:
        return np.zeros(0, dtype=int)
    # separate the parities by a large offset so that they never link
    pts = theta + np.where(parity[:, None] > 0, 0.0, 1e9)
    pairs = cKDTree(pts).query_pairs(link, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def reference_arcs(images, reference):
    """Labels of the arcs with the images nearest to the two reference positions."""
    ref = np.asarray(u.Quantity(reference, u.arcsec).value, dtype=float)
    if ref.shape != (2, 2) or not np.isfinite(ref).all():
        raise ValueError(f"reference must be a (2, 2) angle Quantity, got shape {ref.shape}")
    xy = np.column_stack([images["x"].to_value(u.arcsec), images["y"].to_value(u.arcsec)])
    labels = []
    for r in ref:
        k = int(np.argmin(np.hypot(*(xy - r).T)))
        labels.append(int(images["arc"][k]))
    parities = [int(images["parity"][np.asarray(images["arc"]) == lab][0]) for lab in labels]
    if labels[0] == labels[1] or parities != [1, -1]:
        raise ValueError("reference must point at a positive-parity arc (row 0) and a "
                         f"different, negative-parity arc (row 1); got arcs {labels} with "
                         f"parities {parities}")
    return labels[0], labels[1]


def _fold_arcs(images, n_sources):
    """Labels (L1, L2) of the fold pair of arcs of a constellation.

    The pair of opposite-parity arcs that images the most sources; among
    equals, the pair whose images of the same source lie closest together
    (the two images of a fold pair straddle one critical curve).
    """
    best = None
    arcs = np.unique(np.asarray(images["arc"]))
    src = np.asarray(images["source"])
    xy = np.column_stack([images["x"].to_value(u.arcsec), images["y"].to_value(u.arcsec)])
    parity = np.asarray(images["parity"])
    arc_of = np.asarray(images["arc"])
    info = {}
    for k in arcs:
        sel = np.flatnonzero(arc_of == k)
        # one position per source on this arc (its first image)
        _, first = np.unique(src[sel], return_index=True)
        info[k] = (int(parity[sel[0]]), dict(zip(src[sel][first], xy[sel][first], strict=True)))
    for a in arcs:
        for b in arcs:
            if info[a][0] <= 0 or info[b][0] >= 0:
                continue
            common = sorted(set(info[a][1]) & set(info[b][1]))
            if not common:
                continue
            sep = np.median([np.hypot(*(info[a][1][s] - info[b][1][s])) for s in common])
            score = (len(common), -sep)
            if best is None or score > best[0]:
                best = (score, a, b)
    if best is None:
        raise ValueError("no pair of opposite-parity arcs images a common source")
    return best[1], best[2]

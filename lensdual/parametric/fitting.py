r"""Parametric lens models fitted to a constellation of point-source pairs.

:func:`fit_parametric_lens` fits a lenstronomy lens model (a list of profile
names) to the positions of a pairs table: the two images of every pair must
map back to one source position. The fitted model predicts the magnification
ratio ``mu_model = |mu(L1) / mu(L2)|`` of every pair, which
:func:`compare_with_parametric` confronts with the model-independent size
magnification ``mu_size`` and the flux ratio ``mu_flux`` of
:func:`~lensdual.duality.check_duality`; :func:`plot_parametric_comparison`
draws the three ratios. See :doc:`/parametric_fits` for the method.
"""

import dataclasses
from dataclasses import dataclass

import numpy as np
from astropy import units as u
from astropy.table import QTable, Table

from .._validation import (
    as_angle_scalar,
    as_cosmology,
    as_int,
    as_real,
    as_redshifts,
)
from ..duality import DEFAULT_SNR_THRESHOLD
from ..visualization._parametric import plot_parametric_comparison

__all__ = [
    "DEFAULT_MODEL",
    "PROFILE_DEFAULTS",
    "ParametricFit",
    "fit_parametric_lens",
    "compare_with_parametric",
    "plot_parametric_comparison",
]

#: The default lenstronomy profiles of :func:`fit_parametric_lens` (and of
#: ``lensdual run``'s ``[parametric]`` fit): an elliptical NFW halo and
#: external shear.
DEFAULT_MODEL = ("NFW_ELLIPSE_CSE", "SHEAR")

# (lower, upper, init, log) per parameter; "R" in a string is replaced by the
# data scale (median distance of the images from the frame origin, >= 1 arcsec).
_SCALE = "scale"
_E = (-0.5, 0.5, 0.0, False)
_C = ("-2R", "2R", 0.0, False)

#: Default bounds and initial values of the supported lenstronomy profiles:
#: ``{profile: {param: (lower, upper, init, log)}}``. Strings are multiples of
#: the data scale ``R`` (the median distance of the images from the frame
#: origin, at least 1 arcsec); ``log`` parameters are fitted in log10.
#: Parameters whose bounds are ``None`` are fixed at ``init`` by default
#: (the reference point of SHEAR and CONVERGENCE, which does not change the
#: lensing of point sources up to a constant deflection).
PROFILE_DEFAULTS = {
    "SIS": {"theta_E": (0.01, 200.0, "R", True), "center_x": _C, "center_y": _C},
    "SIE": {"theta_E": (0.01, 200.0, "R", True), "e1": _E, "e2": _E,
            "center_x": _C, "center_y": _C},
    "EPL": {"theta_E": (0.01, 200.0, "R", True), "gamma": (1.2, 2.8, 2.0, False),
            "e1": _E, "e2": _E, "center_x": _C, "center_y": _C},
    "NFW": {"Rs": (0.1, 1000.0, "3R", True), "alpha_Rs": (0.01, 500.0, "R", True),
            "center_x": _C, "center_y": _C},
    "NFW_ELLIPSE_CSE": {"Rs": (0.1, 1000.0, "3R", True), "alpha_Rs": (0.01, 500.0, "R", True),
                        "e1": _E, "e2": _E, "center_x": _C, "center_y": _C},
    "SHEAR": {"gamma1": (-0.5, 0.5, 0.0, False), "gamma2": (-0.5, 0.5, 0.0, False),
              "ra_0": (None, None, 0.0, False), "dec_0": (None, None, 0.0, False)},
    "CONVERGENCE": {"kappa": (-1.0, 1.0, 0.0, False),
                    "ra_0": (None, None, 0.0, False), "dec_0": (None, None, 0.0, False)},
}

CHI2_KINDS = ("source", "image")


def _scaled(value, scale):
    """``value``, with strings like ``"-2R"`` read as multiples of ``scale``."""
    if isinstance(value, str):
        factor = value[:-1]
        factor = {"": 1.0, "-": -1.0}.get(factor, None) or float(factor)
        return factor * scale
    return value


# ---------------------------------------------------------------------- inputs


def _pair_positions(pairs):
    from .._pairs_table import positions as _positions

    if not isinstance(pairs, Table):
        raise TypeError("pairs must be an astropy Table or QTable (the pairs table), got "
                        f"{type(pairs).__name__}")
    theta1, theta2 = _positions(QTable(pairs, copy=False))
    t1, t2 = theta1.to_value(u.arcsec), theta2.to_value(u.arcsec)
    bad = ~(np.isfinite(t1).all(axis=1) & np.isfinite(t2).all(axis=1))
    if bad.any():
        raise ValueError(f"pairs has non-finite positions at row(s) {np.flatnonzero(bad).tolist()}")
    ids = (np.asarray(pairs["pair_id"]) if "pair_id" in pairs.colnames
           else np.arange(1, len(pairs) + 1))
    return t1, t2, ids


def _model_list(model):
    if isinstance(model, str):
        model = (model,)
    try:
        model = list(model)
    except TypeError:
        raise TypeError(f"model must be a profile name or a sequence of names, got {model!r}") \
            from None
    if not model:
        raise ValueError("model must name at least one lenstronomy profile")
    for name in model:
        if not isinstance(name, str):
            raise TypeError(f"model must hold profile names (str), got {name!r}")
        if name not in PROFILE_DEFAULTS:
            raise ValueError(f"model: unknown or unsupported profile {name!r}; supported: "
                             f"{sorted(PROFILE_DEFAULTS)}")
    return model


def _per_component(option, name, model):
    """``{index: dict}`` from a dict keyed by profile name or index (or a list)."""
    out = {i: {} for i in range(len(model))}
    if option is None:
        return out
    if isinstance(option, (list, tuple)):
        if len(option) != len(model):
            raise ValueError(f"{name} as a list must have one dict per model profile "
                             f"({len(model)}), got {len(option)}")
        option = dict(enumerate(option))
    if not isinstance(option, dict):
        raise TypeError(f"{name} must be a dict keyed by profile name or index, got "
                        f"{type(option).__name__}")
    for key, values in option.items():
        if isinstance(key, (int, np.integer)) and not isinstance(key, bool):
            if not 0 <= key < len(model):
                raise ValueError(f"{name}: component index {key} out of range for a model of "
                                 f"{len(model)} profile(s)")
            targets = [int(key)]
        elif isinstance(key, str):
            targets = [i for i, m in enumerate(model) if m == key]
            if not targets:
                raise ValueError(f"{name}: profile {key!r} is not in the model {model}")
        else:
            raise TypeError(f"{name} keys must be profile names or indices, got {key!r}")
        if values is None:
            continue
        if not isinstance(values, dict):
            raise TypeError(f"{name}[{key!r}] must be a dict of parameter values, got "
                            f"{type(values).__name__}")
        for i in targets:
            allowed = PROFILE_DEFAULTS[model[i]]
            unknown = sorted(set(values) - set(allowed))
            if unknown:
                raise ValueError(f"{name}[{key!r}]: unknown parameter(s) {unknown} of "
                                 f"{model[i]}; it has {list(allowed)}")
            out[i].update(values)
    return out


def _fixed_profiles(fixed):
    from lenstronomy.LensModel.lens_model import LensModel

    if fixed is None:
        return [], []
    if not isinstance(fixed, (list, tuple)):
        raise TypeError("fixed must be a list of (profile, kwargs) tuples, got "
                        f"{type(fixed).__name__}")
    names, kwargs = [], []
    for i, item in enumerate(fixed):
        if hasattr(item, "profile") and hasattr(item, "kwargs"):  # a LensComponent
            item = (item.profile, item.kwargs)
        if not (isinstance(item, (list, tuple)) and len(item) == 2
                and isinstance(item[0], str) and isinstance(item[1], dict)):
            raise TypeError(f"fixed[{i}] must be a (profile name, kwargs dict) tuple, got {item!r}")
        prof, kw = item
        try:
            func = LensModel([prof]).lens_model.func_list[0]
        except Exception as exc:
            raise ValueError(f"fixed[{i}]: unknown lenstronomy profile {prof!r}") from exc
        pnames = list(getattr(func, "param_names", kw.keys()))
        missing = sorted(set(pnames) - set(kw))
        unknown = sorted(set(kw) - set(pnames))
        if missing or unknown:
            raise ValueError(f"fixed[{i}] ({prof}): missing keyword(s) {missing}, unknown "
                             f"keyword(s) {unknown}")
        bad = [k for k, v in kw.items() if not np.all(np.isfinite(v))]
        if bad:
            raise ValueError(f"fixed[{i}] ({prof}): non-finite value of {bad}")
        names.append(prof)
        kwargs.append({k: (float(v) if np.ndim(v) == 0 else v) for k, v in kw.items()})
    return names, kwargs


class _Parametrisation:
    """Maps the free-parameter vector to lenstronomy kwargs (private)."""

    def __init__(self, model, scale, fixed_params, bounds, init):
        self.model = model
        self.names = []     # (component, param)
        self.lower, self.upper, self.start, self.log = [], [], [], []
        self.fixed = []     # per component: dict of fixed values
        for i, prof in enumerate(model):
            fix = {}
            for par, (lo, hi, ini, log) in PROFILE_DEFAULTS[prof].items():
                lo, hi, ini = (_scaled(v, scale) if v is not None else None
                               for v in (lo, hi, ini))
                if par in bounds[i]:
                    b = bounds[i][par]
                    if not (isinstance(b, (tuple, list)) and len(b) == 2):
                        raise ValueError(f"bounds of {prof}.{par} must be a (lower, upper) pair, "
                                         f"got {b!r}")
                    lo = as_real(b[0], f"bounds[{prof}][{par}][0]")
                    hi = as_real(b[1], f"bounds[{prof}][{par}][1]")
                    if not lo < hi:
                        raise ValueError(f"bounds of {prof}.{par}: lower {lo} must be < upper {hi}")
                    if log and lo <= 0:
                        raise ValueError(f"bounds of {prof}.{par} must be > 0 (fitted in log10)")
                if par in init[i]:
                    ini = as_real(init[i][par], f"init[{prof}][{par}]")
                if par in fixed_params[i]:
                    fix[par] = as_real(fixed_params[i][par], f"fixed_params[{prof}][{par}]")
                    continue
                if lo is None:
                    if par in bounds[i] or par in init[i]:
                        raise ValueError(f"{prof}.{par} is fixed by default; pass it in "
                                         "fixed_params to change its value")
                    fix[par] = float(ini)
                    continue
                if not lo <= ini <= hi:
                    raise ValueError(f"init of {prof}.{par} = {ini} is outside its bounds "
                                     f"({lo}, {hi})")
                self.names.append((i, par))
                tr = np.log10 if log else (lambda v: v)
                self.lower.append(tr(lo))
                self.upper.append(tr(hi))
                self.start.append(tr(ini))
                self.log.append(log)
            self.fixed.append(fix)
        self.lower = np.array(self.lower, float)
        self.upper = np.array(self.upper, float)
        self.start = np.array(self.start, float)
        self.log = np.array(self.log, bool)

    @property
    def n_free(self):
        return len(self.names)

    def kwargs(self, p):
        out = [dict(f) for f in self.fixed]
        values = np.where(self.log, 10.0 ** np.asarray(p), p)
        for (i, par), v in zip(self.names, values, strict=True):
            out[i][par] = float(v)
        return out

    def labels(self):
        return [f"{self.model[i]}[{i}].{par}" for i, par in self.names]


# ---------------------------------------------------------------------- lensing


def _beta_and_jac(lens_model, kwargs, x, y):
    bx, by = lens_model.ray_shooting(x, y, kwargs)
    fxx, fxy, fyx, fyy = lens_model.hessian(x, y, kwargs)
    jac = np.empty((np.size(x), 2, 2))          # d beta / d theta
    jac[:, 0, 0] = 1 - fxx
    jac[:, 0, 1] = -fxy
    jac[:, 1, 0] = -fyx
    jac[:, 1, 1] = 1 - fyy
    return np.column_stack([bx, by]), jac


def _source_solution(lens_model, kwargs, theta):
    """beta, A = d theta / d beta per image, and the best source of every pair.

    ``theta`` is (2N, 2): the N L1 images then the N L2 images.
    """
    n = len(theta) // 2
    beta, jac = _beta_and_jac(lens_model, kwargs, theta[:, 0], theta[:, 1])
    with np.errstate(all="ignore"):
        amat = np.linalg.inv(jac)
        metric = np.einsum("nki,nkj->nij", amat, amat)       # A^T A
        msum = metric[:n] + metric[n:]
        rhs = (np.einsum("nij,nj->ni", metric[:n], beta[:n])
               + np.einsum("nij,nj->ni", metric[n:], beta[n:]))
        src = np.linalg.solve(msum, rhs[..., None])[..., 0]
    return beta, jac, amat, src


def _newton_images(lens_model, kwargs, theta, src, n_iter=8):
    """Images of ``src`` (per pair, repeated for both arcs) nearest to ``theta``."""
    target = np.concatenate([src, src])
    th = theta.copy()
    for _ in range(n_iter):
        beta, jac = _beta_and_jac(lens_model, kwargs, th[:, 0], th[:, 1])
        with np.errstate(all="ignore"):
            step = np.linalg.solve(jac, (beta - target)[..., None])[..., 0]
        th = th - step
    return th


def _residuals(lens_model, kwargs, theta, sigma, kind):
    beta, jac, amat, src = _source_solution(lens_model, kwargs, theta)
    n = len(theta) // 2
    if kind == "source":
        d = np.einsum("nij,nj->ni", amat, beta - np.concatenate([src, src]))
    else:
        d = _newton_images(lens_model, kwargs, theta, src[:n]) - theta
    r = d.ravel() / sigma
    if not np.isfinite(r).all():
        r = np.where(np.isfinite(r), r, 1e6)
    return r


# ---------------------------------------------------------------------- result


@dataclass(kw_only=True, eq=False, repr=False, frozen=True)
class ParametricFit:
    """The result of :func:`fit_parametric_lens` (made by it, not by hand).

    Every parameter is also an attribute of the same name.

    Parameters
    ----------
    model : list of str
        The fitted lenstronomy profiles (the fixed ones follow them in
        ``lens_model``).
    kwargs_fitted : list of dict
        Best-fit keyword arguments of the fitted profiles.
    kwargs_lens : list of dict
        Keyword arguments of every profile of ``lens_model`` (fitted, then
        fixed).
    lens_model : lenstronomy ``LensModel``
        The model (fitted plus fixed profiles).
    param_names : list of str
        Free parameters, ``"PROFILE[index].name"``; log10 of ``theta_E``,
        ``Rs`` and ``alpha_Rs`` are fitted, but ``best_params`` holds linear values.
    best_params : dict
        Best-fit values of the free parameters (linear).
    covariance : ndarray
        Laplace-approximation covariance of the free parameters in the fitted
        (log10 where applicable) space, ``(J^T J)^+``.
    chi2, dof, reduced_chi2 : float, int, float
        Best-fit chi-square (of kind ``chi2_kind``), ``2 * n_pairs - n_free``
        and their ratio.
    chi2_kind : str
        The chi-square that was minimised (``chi2`` of
        :func:`fit_parametric_lens`).
    success : bool
        Whether the least-squares optimiser reported convergence.
    z_lens, z_source : float
        Redshifts of the fit.
    cosmology : `~astropy.cosmology.Cosmology`
        Its cosmology.
    sigma_pos : `~astropy.units.Quantity`
        The position error of the fit.
    fixed_profiles : list of str
        The fixed profiles that follow the fitted ones in ``lens_model``.
    _param, _p_best, _fixed_kwargs
        The fit's internals (private): the parameter map, the best fit in
        the fitted space and the fixed profiles' keyword arguments.
    samples : ndarray or None
        Posterior sample of the free parameters (fitted space), shape
        (n, n_free): emcee's flattened chain after burn-in, when
        ``mcmc=True``; else None.
    acceptance : float or None
        Mean acceptance fraction of the emcee walkers (``mcmc=True``).
    autocorr_time : ndarray or None
        emcee's integrated autocorrelation time of every free parameter, in
        steps (``mcmc=True``); reliable only when the chain is at least ~50
        times the largest one (``mcmc_info["converged"]``).
    mcmc_info : dict or None
        The sampler's settings and diagnostics (``mcmc=True``; also in
        ``predictions.meta["mcmc"]``): ``sampler``, ``emcee_version``,
        ``n_walkers``, ``n_steps`` (per walker), ``burn_in`` (steps
        discarded), ``acceptance_fraction`` (mean) and
        ``acceptance_fraction_min`` (worst walker), ``autocorr_time``
        (``{param name: tau}``), ``n_autocorr`` (kept steps over the largest
        tau) and ``converged`` (``n_autocorr >= 50``).
    predictions : `~astropy.table.QTable`
        Per pair: ``pair_id``, ``mu1_model``, ``mu2_model`` (signed),
        ``mu_model = |mu1/mu2|``, ``mu_model_err`` (half the 16-84 %
        width over the parameter sample: robust to the draws that move a
        critical curve onto an image), ``mu_model_p16``, ``mu_model_p84``, the
        best-fit source ``beta_x``, ``beta_y``, and the image-plane residuals
        ``dx1, dy1, dx2, dy2`` (model image minus measured position, the
        model image found by Newton's method from the measured one).
    """

    model: list
    kwargs_fitted: list
    kwargs_lens: list
    lens_model: object
    param_names: list
    best_params: dict
    covariance: np.ndarray
    chi2: float
    dof: int
    reduced_chi2: float
    chi2_kind: str
    samples: np.ndarray | None
    acceptance: float | None
    autocorr_time: np.ndarray | None
    mcmc_info: dict | None
    success: bool
    z_lens: float
    z_source: float
    cosmology: object
    sigma_pos: u.Quantity
    fixed_profiles: list
    predictions: QTable | None
    # the fit's internals, for predictions from the parameter sample
    _param: object
    _p_best: np.ndarray
    _fixed_kwargs: list

    def __repr__(self):
        return (f"<ParametricFit model={self.model} chi2={self.chi2:.3g} dof={self.dof} "
                f"n_pairs={len(self.predictions)}>")

    def _param_sample(self, n, rng):
        if self.samples is not None:
            idx = rng.integers(0, len(self.samples), n) if len(self.samples) > n else slice(None)
            return self.samples[idx]
        cov = 0.5 * (self.covariance + self.covariance.T)
        draws = rng.multivariate_normal(self._p_best, cov, size=n, method="eigh")
        return np.clip(draws, self._param.lower, self._param.upper)

    def _full_kwargs(self, p):
        return self._param.kwargs(p) + [dict(k) for k in self._fixed_kwargs]

    def _linear(self, p):
        """Parameter vectors of the fitted space in linear values."""
        return np.where(self._param.log, 10.0 ** np.asarray(p, float), p)

    def parameter_intervals(self, level=0.6827):
        """Median and central credible interval of every free parameter.

        Parameters
        ----------
        level : float
            Probability in the interval (default 0.6827, the 16-84 %
            interval).

        Returns
        -------
        table : `~astropy.table.QTable`
            ``name``, ``best`` (best fit), ``median``, ``lower``, ``upper``
            (linear values). From the posterior sample (``mcmc=True``),
            else from the Laplace approximation (best fit +- its quantile
            in the fitted, log10 where applicable, space, clipped to the
            bounds).
        """
        from scipy.stats import norm

        level = as_real(level, "level", minimum=0.0, maximum=1.0)
        if not 0.0 < level < 1.0:
            raise ValueError(f"level must be between 0 and 1 (exclusive), got {level}")
        if self.samples is not None:
            q = 100 * np.array([0.5 - level / 2, 0.5, 0.5 + level / 2])
            lower, median, upper = np.percentile(self.samples, q, axis=0)
        else:
            with np.errstate(invalid="ignore"):
                half = norm.ppf(0.5 + level / 2) * np.sqrt(np.diag(self.covariance))
            median = self._p_best
            lower = np.clip(self._p_best - half, self._param.lower, self._param.upper)
            upper = np.clip(self._p_best + half, self._param.lower, self._param.upper)
        tab = QTable()
        tab["name"] = list(self.param_names)
        tab["best"] = self._linear(self._p_best)
        tab["median"] = self._linear(median)
        tab["lower"] = self._linear(lower)
        tab["upper"] = self._linear(upper)
        tab.meta["level"] = level
        tab.meta["source"] = "posterior sample" if self.samples is not None else "Laplace"
        return tab

    def plot_corner(self, *, truths=None, fig=None, **kwargs):
        """Corner plot of the posterior sample (``mcmc=True``), with corner.

        Parameters
        ----------
        truths : dict, sequence, "best" or None
            Values to mark (linear): ``{param name: value}`` (names as in
            ``param_names``; missing ones are not marked), one value per
            free parameter (None for none), or ``"best"`` for the best fit.
        fig : `matplotlib.figure.Figure`, optional
            Figure to draw on (it must have ``n_free**2`` axes or none).
        **kwargs
            Passed to ``corner.corner`` (e.g. ``quantiles=[0.16, 0.5,
            0.84]``, ``show_titles=True``); ``labels`` defaults to
            ``param_names``.

        Returns
        -------
        fig : `matplotlib.figure.Figure`
            ``n_free x n_free`` axes: the marginal histograms on the
            diagonal, one panel per parameter pair below it (the panels
            above are hidden). Parameters are shown in linear values.

        Raises
        ------
        ImportError
            corner is not installed (``pip install "lensdual[mcmc]"``).
        ValueError
            The fit has no posterior sample (fitted with ``mcmc=False``).
        """
        corner = _import_optional("corner", "ParametricFit.plot_corner")
        if self.samples is None:
            raise ValueError("this fit has no posterior sample: fit with "
                             "fit_parametric_lens(..., mcmc=True) to draw a corner plot")
        names = list(self.param_names)
        if truths is None:
            marks = None
        elif isinstance(truths, str):
            if truths != "best":
                raise ValueError(f'truths must be a dict, a sequence, "best" or None, '
                                 f"got {truths!r}")
            marks = [self.best_params[n] for n in names]
        elif isinstance(truths, dict):
            unknown = sorted(set(truths) - set(names))
            if unknown:
                raise ValueError(f"truths: unknown parameter(s) {unknown}; the free "
                                 f"parameters are {names}")
            marks = [truths.get(n) for n in names]
        else:
            marks = list(truths)
            if len(marks) != len(names):
                raise ValueError(f"truths must have one value per free parameter "
                                 f"({len(names)}: {names}), got {len(marks)}")
        if marks is not None:
            marks = [None if v is None else as_real(v, f"truths[{n!r}]")
                     for n, v in zip(names, marks, strict=True)]
        kwargs.setdefault("labels", names)
        return corner.corner(self._linear(self.samples), truths=marks, fig=fig, **kwargs)

    def magnification_ratio(self, theta1, theta2, *, n_samples=300, seed=None):
        """Model magnifications at image positions, with sample-based errors.

        Parameters
        ----------
        theta1, theta2 : `~astropy.units.Quantity`, shape (N, 2)
            L1 and L2 image positions (frame of the fit).
        n_samples : int
            Parameter draws for the error (posterior sample when there is
            one, else the Laplace approximation).
        seed : int, `numpy.random.Generator` or None
            Seed of the draws.

        Returns
        -------
        table : `~astropy.table.QTable`
            ``mu1_model``, ``mu2_model``, ``mu_model``, ``mu_model_err``,
            ``mu_model_p16``, ``mu_model_p84``.
        """
        from .._validation import as_positions

        t1 = as_positions(theta1, "theta1")
        t2 = as_positions(theta2, "theta2")
        if len(t1) != len(t2):
            raise ValueError(f"theta1 and theta2 differ in length ({len(t1)} != {len(t2)})")
        n_samples = as_int(n_samples, "n_samples", minimum=2)
        rng = np.random.default_rng(seed)
        theta = np.concatenate([t1, t2])
        n = len(t1)

        def mags(kwargs):
            _, jac = _beta_and_jac(self.lens_model, kwargs, theta[:, 0], theta[:, 1])
            with np.errstate(divide="ignore"):
                mu = 1.0 / np.linalg.det(jac)
            return mu[:n], mu[n:]

        mu1, mu2 = mags(self.kwargs_lens)
        ratios = np.array([np.abs(np.divide(*mags(self._full_kwargs(p))))
                           for p in self._param_sample(n_samples, rng)])
        tab = QTable()
        tab["mu1_model"] = mu1
        tab["mu2_model"] = mu2
        tab["mu_model"] = np.abs(mu1 / mu2)
        p16, p84 = np.percentile(ratios, [16, 84], axis=0)
        tab["mu_model_err"] = 0.5 * (p84 - p16)
        tab["mu_model_p16"], tab["mu_model_p84"] = p16, p84
        return tab


# ---------------------------------------------------------------------- fitting


def _import_optional(name, purpose):
    """Import an optional dependency of the ``mcmc`` extra, or say how to get it."""
    import importlib

    try:
        return importlib.import_module(name)
    except ImportError as exc:
        raise ImportError(
            f"{purpose} needs the optional package {name!r}, which is not installed; "
            f'install it with: pip install "lensdual[mcmc]"'
        ) from exc


#: Chains shorter than this many integrated autocorrelation times are flagged.
N_AUTOCORR = 50


def _initial_walkers(p_best, cov, lower, upper, n_walkers, rng):
    """Walkers drawn from the Laplace approximation about the best fit (private).

    A draw outside the bounds is reflected at the bound, and drawn uniformly
    inside the bounds when still outside; a small per-parameter jitter keeps
    the walkers off any exactly degenerate direction of the covariance (the
    stretch move never leaves the span of the initial ensemble).
    """
    d = len(p_best)
    width = upper - lower
    cov = 0.5 * (cov + cov.T)
    if not (np.all(np.isfinite(cov)) and np.trace(cov) > 0):
        cov = np.diag((width * 1e-3) ** 2)
    vals, vecs = np.linalg.eigh(cov)
    root = vecs * np.sqrt(np.clip(vals, 0.0, None))
    std = np.maximum(np.sqrt(np.clip(np.diag(cov), 0.0, None)), 1e-6 * width)
    z = rng.standard_normal((n_walkers, d))
    x = p_best + z @ root.T + 1e-2 * std * rng.standard_normal((n_walkers, d))
    x = np.where(x > upper, 2 * upper - x, x)
    x = np.where(x < lower, 2 * lower - x, x)
    out = (x < lower) | (x > upper)
    if out.any():
        x = np.where(out, rng.uniform(lower, upper, (n_walkers, d)), x)
    return x


def _run_emcee(emcee, logp, p_best, cov, lower, upper, n_walkers, n_steps, rng, labels):
    """Sample with ``emcee.EnsembleSampler``; chain after burn-in and diagnostics."""
    d = len(p_best)

    def log_prob(p):
        if np.any(p < lower) or np.any(p > upper):
            return -np.inf
        return logp(p)

    p0 = _initial_walkers(p_best, cov, lower, upper, n_walkers, rng)
    # differential-evolution moves (with 20 % snooker moves): on near-Gaussian posteriors
    # their autocorrelation time is ~3 times shorter than that of the default stretch move
    moves = [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    sampler = emcee.EnsembleSampler(n_walkers, d, log_prob, moves=moves)
    # emcee draws from a legacy RandomState: seed it from the fit's Generator
    sampler.random_state = np.random.RandomState(
        int(rng.integers(0, 2**32, dtype=np.uint64))).get_state()
    sampler.run_mcmc(p0, n_steps, progress=False)
    burn = n_steps // 4
    samples = sampler.get_chain(discard=burn, flat=True)
    acceptance = np.asarray(sampler.acceptance_fraction, float)
    n_kept = n_steps - burn
    with np.errstate(all="ignore"):
        tau = np.asarray(emcee.autocorr.integrated_time(
            sampler.get_chain(discard=burn), tol=0, quiet=True), float)
    tau_max = float(np.max(tau)) if np.all(np.isfinite(tau)) else np.nan
    n_tau = n_kept / tau_max if np.isfinite(tau_max) and tau_max > 0 else np.nan
    converged = bool(np.isfinite(n_tau) and n_tau >= N_AUTOCORR)
    info = {
        "sampler": "emcee.EnsembleSampler",
        "moves": "0.8 DEMove + 0.2 DESnookerMove",
        "emcee_version": str(emcee.__version__),
        "n_walkers": int(n_walkers),
        "n_steps": int(n_steps),
        "burn_in": int(burn),
        "acceptance_fraction": float(np.mean(acceptance)),
        "acceptance_fraction_min": float(np.min(acceptance)),
        "autocorr_time": dict(zip(labels, tau.tolist(), strict=True)),
        "n_autocorr": float(n_tau),
        "converged": converged,
    }
    if not converged:
        import warnings

        from ..exceptions import LensdualWarning

        what = (f"{n_kept} steps per walker after burn-in are {n_tau:.1f} integrated "
                f"autocorrelation times (max tau = {tau_max:.1f} steps)"
                if np.isfinite(n_tau) else
                "the integrated autocorrelation time could not be estimated (a parameter "
                "never moved)")
        warnings.warn(f"emcee chain too short: {what}; fewer than {N_AUTOCORR} "
                      "autocorrelation times, so the posterior sample, mu_model_err and "
                      "autocorr_time are not reliable: increase n_mcmc", LensdualWarning,
                      stacklevel=3)
    return samples, float(np.mean(acceptance)), tau, info


def _mcmc_walkers(n_walkers, n_free, n_mcmc):
    """(walkers, steps per walker) of the MCMC, checked against the free parameters."""
    if n_walkers is None:
        n_walkers = max(8, 2 * n_free)
    if n_walkers < 2 * n_free:
        raise ValueError(f"n_walkers must be >= 2 * n_free = {2 * n_free} (emcee's "
                         f"ensemble moves), got {n_walkers}")
    n_steps = n_mcmc // n_walkers
    if n_steps < 4:
        raise ValueError(f"n_mcmc = {n_mcmc} gives {n_steps} step(s) per walker for "
                         f"{n_walkers} walkers; need n_mcmc >= {4 * n_walkers}")
    return n_walkers, n_steps


def _multi_start(resid, param, n_starts, max_nfev, rng):
    """The best of ``n_starts`` bounded least-squares fits (the first from ``param.start``)."""
    from scipy.optimize import least_squares

    starts = [np.clip(param.start, param.lower, param.upper)]
    for _ in range(n_starts - 1):
        starts.append(rng.uniform(param.lower, param.upper))
    best = None
    for p0 in starts:
        # keep away from the bounds, where least_squares' trust region stalls
        p0 = np.clip(p0, param.lower + 1e-6 * (param.upper - param.lower),
                     param.upper - 1e-6 * (param.upper - param.lower))
        res = least_squares(resid, p0, bounds=(param.lower, param.upper), method="trf",
                            jac="3-point", x_scale="jac", max_nfev=max_nfev, xtol=1e-12, ftol=1e-12,
                            gtol=1e-12)
        if best is None or res.cost < best.cost:
            best = res
    return best


def fit_parametric_lens(pairs, *, model=DEFAULT_MODEL, z_lens=None,
                        z_source=None, cosmology=None, sigma_pos=0.06 * u.arcsec, fixed=None,
                        fixed_params=None, bounds=None, init=None, n_starts=8, max_nfev=2000,
                        mcmc=False, n_mcmc=4000, n_walkers=None, n_samples=300, seed=None,
                        chi2="source"):
    r"""Fit a parametric lenstronomy lens model to a constellation of pairs.

    Every pair's two images (``x1, y1`` on arc L1 and ``x2, y2`` on arc L2)
    must map back to one source. The source positions are not free
    parameters: for given lens parameters, the best source of each pair is
    solved for in closed form, so each pair gives ``2`` constraints
    (``4`` coordinates minus ``2`` source coordinates).

    Parameters
    ----------
    pairs : `~astropy.table.Table`
        A pairs table (:ref:`pairs-table`), positions in the frame of the
        model (lens-centred for the default bounds).
    model : str or sequence of str
        lenstronomy profiles to fit, among ``SIS``, ``SIE``, ``EPL``, ``NFW``,
        ``NFW_ELLIPSE_CSE``, ``SHEAR`` and ``CONVERGENCE`` (default
        ``("NFW_ELLIPSE_CSE", "SHEAR")``).
    z_lens, z_source : float
        Lens and source redshifts (required; they set the lenstronomy
        ``LensModel``'s distances, for physical units downstream).
    cosmology : `~astropy.cosmology.Cosmology`, optional
        Defaults to flat LambdaCDM, H0 = 70, Om0 = 0.3.
    sigma_pos : `~astropy.units.Quantity`
        Positional uncertainty of every image (default 0.06 arcsec).
    fixed : list of (str, dict) or `~lensdual.simulation.LensComponent`, optional
        Extra profiles with fixed parameters added to the model (e.g.
        cluster members from a light-traces-mass model).
    fixed_params : dict, optional
        Parameters held fixed, ``{profile name or index: {param: value}}``,
        e.g. ``{"NFW_ELLIPSE_CSE": {"center_x": 0.0, "center_y": 0.0}}``.
    bounds : dict, optional
        ``{profile name or index: {param: (lower, upper)}}`` replacing the
        defaults of :data:`PROFILE_DEFAULTS`.
    init : dict, optional
        ``{profile name or index: {param: value}}``: the first start.
    n_starts : int
        Local optimisations: the first from ``init``, the others from points
        drawn uniformly inside the bounds (log-uniformly for scale
        parameters). Default 8.
    max_nfev : int
        Function evaluations per local optimisation (default 2000).
    mcmc : bool
        Sample the posterior (flat priors inside the bounds) with emcee's
        affine-invariant ensemble sampler (`emcee.EnsembleSampler`), its
        walkers started from the Laplace approximation about the best fit.
        Needs the optional ``mcmc`` extra (``pip install "lensdual[mcmc]"``);
        an `ImportError` says so, before any fitting, when emcee is missing.
    n_mcmc : int
        Posterior evaluations of the sampler, all walkers together (default
        4000): ``n_mcmc // n_walkers`` steps per walker, of which the first
        quarter is discarded as burn-in.
    n_walkers : int, optional
        emcee walkers, at least ``2 * n_free`` (default
        ``max(8, 2 * n_free)``).
    n_samples : int
        Parameter draws for the errors of ``mu_model`` (from the posterior
        sample with ``mcmc=True``, else from the Laplace approximation).
    seed : int, `numpy.random.Generator` or None
        Seed of the starting points, the sampler (its walkers and emcee's
        random state) and the error draws: equal seeds give equal results.
    chi2 : {"source", "image"}
        Chi-square (see Notes).

    Returns
    -------
    fit : `ParametricFit`

    Raises
    ------
    TypeError
        Wrong argument types (e.g. positions without units).
    ValueError
        Unknown profile names, missing redshifts, bad bounds, or fewer
        constraints (``2 * n_pairs``) than free parameters + 1 -- all before
        any fitting starts.
    ImportError
        ``mcmc=True`` without emcee installed (before any fitting).

    Warns
    -----
    `~lensdual.exceptions.LensdualWarning`
        With ``mcmc=True``, when the chain after burn-in is shorter than
        ``N_AUTOCORR = 50`` integrated autocorrelation times (or they cannot
        be estimated): the sample is then not a reliable posterior.

    Notes
    -----
    **Chi-square.** The default, ``chi2="source"``, is the
    magnification-weighted source-plane chi-square

    .. math::

        \chi^2 = \sum_{a}\sum_{i=1,2}
        \frac{|A_{a,i}\,(\beta_{a,i} - \hat\beta_a)|^2}{\sigma_{\rm pos}^2},

    with :math:`\beta_{a,i}` the ray-traced position of image :math:`i` of
    pair :math:`a`, :math:`A = \partial\theta/\partial\beta` the local
    magnification matrix, and :math:`\hat\beta_a` the source minimising it,
    :math:`\hat\beta_a = (\sum_i M_i)^{-1}\sum_i M_i\beta_{a,i}`,
    :math:`M_i = A_i^T A_i`. Since :math:`\theta_{\rm model} - \theta
    \approx A(\hat\beta - \beta)` to first order, this is the image-plane
    chi-square without solving the lens equation: it is as cheap as a plain
    source-plane chi-square (one ray-shooting and one Hessian per image)
    but, unlike it, does not reward models that shrink the source plane
    (highly magnifying models), and it weights the images by their
    measured, image-plane, errors. It is accurate while the residuals are
    small compared with the scale over which ``A`` varies, i.e. near a good
    fit and away from critical curves. ``chi2="image"`` refines each model
    image with Newton's method (8 steps) from the measured position towards
    the source :math:`\hat\beta_a`, and uses the true image-plane offsets:
    about 8 times slower; it only finds the image nearest to the measured one
    (no global image search, so a model that loses an image is not
    penalised beyond the Newton failure, which gets a large residual).

    **Optimiser.** `scipy.optimize.least_squares` (trust-region reflective,
    central finite-difference Jacobian -- the forward one stalls -- within
    the bounds) on the residual vector, from ``n_starts`` starting points;
    the lowest chi-square wins.

    **Errors.** The covariance of the free parameters is the Laplace
    approximation ``(J^T J)^+`` at the best fit (``J`` the Jacobian of the
    normalised residuals); ``mu_model_err`` is half the 16-84 % width of
    ``|mu1/mu2|`` over ``n_samples`` parameter vectors drawn from it (or
    from the emcee posterior sample with ``mcmc=True``).

    **MCMC.** With ``mcmc=True`` the posterior :math:`\propto
    \exp(-\chi^2/2)` (flat priors inside the bounds, in the fitted space:
    log10 for ``theta_E``, ``Rs``, ``alpha_Rs``) is sampled by
    `emcee.EnsembleSampler` (differential-evolution moves, 20 % of them
    snooker moves: about 3 times shorter autocorrelation times than the
    default stretch move on a Gaussian). Its walkers start from draws of
    the Laplace approximation about the best fit (reflected into the
    bounds), so the burn-in is short; the first quarter of the steps is
    discarded all the same. ``fit.samples`` is the flattened chain after
    burn-in, ``fit.acceptance`` its mean acceptance fraction,
    ``fit.autocorr_time`` emcee's integrated autocorrelation time per
    parameter (in steps) and ``fit.mcmc_info`` all the diagnostics; a
    `~lensdual.exceptions.LensdualWarning` flags a chain shorter than 50
    autocorrelation times. :meth:`ParametricFit.plot_corner` draws the
    sample with corner.

    **Degeneracies.** Positions only constrain the lens up to the
    mass-sheet degeneracy: a ``CONVERGENCE`` sheet together with a rescaling
    of the rest of the model leaves every position unchanged (the sources
    are free), so a model with ``CONVERGENCE`` has one exactly degenerate
    direction (its magnification *ratios* are invariant, so
    ``mu_model`` is not affected). A single fold pair of arcs
    constrains the deflection field only locally (the relative Jacobian
    between the arcs and its gradient): the lens centre, and the trade-off
    between the halo's scale radius and normalisation, are poorly
    constrained; fix the centre (``fixed_params``) when it is known, e.g.
    from the BCG. The reference points ``ra_0, dec_0`` of SHEAR and
    CONVERGENCE are always fixed.
    """
    from lenstronomy.LensModel.lens_model import LensModel

    # ---- validation, all before fitting
    if z_lens is None or z_source is None:
        raise ValueError("z_lens and z_source are required (got "
                         f"z_lens={z_lens!r}, z_source={z_source!r})")
    zl, zs = as_redshifts(z_lens, z_source)
    cosmo = as_cosmology(cosmology)
    sigma = as_angle_scalar(sigma_pos, "sigma_pos", allow_zero=False)
    if not isinstance(chi2, str) or chi2 not in CHI2_KINDS:
        raise ValueError(f"chi2 must be one of {list(CHI2_KINDS)}, got {chi2!r}")
    if not isinstance(mcmc, bool):
        raise TypeError(f"mcmc must be True or False, got {mcmc!r}")
    n_starts = as_int(n_starts, "n_starts", minimum=1)
    max_nfev = as_int(max_nfev, "max_nfev", minimum=10)
    n_mcmc = as_int(n_mcmc, "n_mcmc", minimum=100)
    if n_walkers is not None:
        n_walkers = as_int(n_walkers, "n_walkers", minimum=2)
    emcee = _import_optional("emcee", "fit_parametric_lens(mcmc=True)") if mcmc else None
    n_samples = as_int(n_samples, "n_samples", minimum=2)
    profiles = _model_list(model)
    t1, t2, ids = _pair_positions(pairs)
    n_pairs = len(t1)
    fixed_names, fixed_kwargs = _fixed_profiles(fixed)
    theta = np.concatenate([t1, t2])
    scale = max(1.0, float(np.median(np.hypot(theta[:, 0], theta[:, 1])))) if n_pairs else 1.0
    param = _Parametrisation(
        profiles, scale,
        _per_component(fixed_params, "fixed_params", profiles),
        _per_component(bounds, "bounds", profiles),
        _per_component(init, "init", profiles),
    )
    n_free = param.n_free
    if n_free == 0:
        raise ValueError("no free parameters: everything is fixed")
    if 2 * n_pairs <= n_free:
        raise ValueError(
            f"too few pairs: {n_pairs} pair(s) give {2 * n_pairs} constraints (2 per pair "
            f"after eliminating its source position) for {n_free} free parameter(s) "
            f"({param.labels()}); need 2 * n_pairs > n_free: add pairs or fix parameters "
            "(fixed_params)"
        )
    if mcmc:
        n_walkers, n_steps = _mcmc_walkers(n_walkers, n_free, n_mcmc)
    rng = np.random.default_rng(seed)

    # ---- fitting
    lens_model = LensModel(profiles + fixed_names, z_lens=zl, z_source=zs, cosmo=cosmo)

    def resid(p):
        return _residuals(lens_model, param.kwargs(p) + fixed_kwargs, theta, sigma, chi2)

    best = _multi_start(resid, param, n_starts, max_nfev, rng)
    p_best = best.x
    chi2_best = float(2 * best.cost)
    jtj = best.jac.T @ best.jac
    cov = np.linalg.pinv(jtj, rcond=1e-12, hermitian=True)

    samples, acceptance, autocorr_time, mcmc_info = None, None, None, None
    if mcmc:
        def logp(p):
            return -0.5 * float(np.sum(resid(p) ** 2))
        samples, acceptance, autocorr_time, mcmc_info = _run_emcee(
            emcee, logp, p_best, cov, param.lower, param.upper, n_walkers, n_steps, rng,
            param.labels())

    kwargs_fitted = param.kwargs(p_best)
    values = np.where(param.log, 10.0 ** p_best, p_best)
    fit = ParametricFit(
        model=profiles, kwargs_fitted=kwargs_fitted,
        kwargs_lens=kwargs_fitted + [dict(k) for k in fixed_kwargs],
        lens_model=lens_model, param_names=param.labels(),
        best_params=dict(zip(param.labels(), values.tolist(), strict=True)),
        covariance=cov, chi2=chi2_best, dof=2 * n_pairs - n_free,
        reduced_chi2=chi2_best / (2 * n_pairs - n_free), chi2_kind=chi2, samples=samples,
        acceptance=acceptance, autocorr_time=autocorr_time, mcmc_info=mcmc_info,
        success=bool(best.success), z_lens=zl, z_source=zs,
        cosmology=cosmo, sigma_pos=sigma * u.arcsec, fixed_profiles=fixed_names,
        _param=param, _p_best=p_best, _fixed_kwargs=fixed_kwargs, predictions=None,
    )

    # ---- predictions
    pred = fit.magnification_ratio(t1 * u.arcsec, t2 * u.arcsec, n_samples=n_samples, seed=rng)
    _, _, _, src = _source_solution(lens_model, fit.kwargs_lens, theta)
    model_theta = _newton_images(lens_model, fit.kwargs_lens, theta, src)
    d = model_theta - theta
    tab = QTable()
    tab["pair_id"] = ids
    for name in pred.colnames:
        tab[name] = pred[name]
    tab["beta_x"] = src[:, 0] * u.arcsec
    tab["beta_y"] = src[:, 1] * u.arcsec
    tab["dx1"], tab["dy1"] = d[:n_pairs, 0] * u.arcsec, d[:n_pairs, 1] * u.arcsec
    tab["dx2"], tab["dy2"] = d[n_pairs:, 0] * u.arcsec, d[n_pairs:, 1] * u.arcsec
    tab.meta["model"] = profiles
    tab.meta["chi2"] = chi2_best
    tab.meta["dof"] = fit.dof
    if mcmc_info is not None:
        tab.meta["mcmc"] = mcmc_info
    fit = dataclasses.replace(fit, predictions=tab)
    return fit


# ---------------------------------------------------------------------- comparison


def _ln_err(tab, name):
    """Error of ln(name) from its p16/p84 columns, else from name_err."""
    value = np.asarray(tab[name], dtype=float)
    if f"{name}_p16" in tab.colnames and f"{name}_p84" in tab.colnames:
        with np.errstate(all="ignore"):
            return 0.5 * (np.log(np.asarray(tab[f"{name}_p84"], float))
                          - np.log(np.asarray(tab[f"{name}_p16"], float)))
    with np.errstate(all="ignore"):
        return np.asarray(tab[f"{name}_err"], dtype=float) / value


def compare_with_parametric(duality_table, fit, *, z_source=None,
                            snr_threshold=DEFAULT_SNR_THRESHOLD,
                            n_samples=300, seed=None):
    r"""Compare flux ratios with the size magnification and a parametric model.

    Parameters
    ----------
    duality_table : `~astropy.table.Table`
        Output of :func:`~lensdual.duality.check_duality` (needs the
        positions, ``mu_flux``, ``mu_flux_err``, ``mu_size``, ``mu_size_err``).
    fit : `ParametricFit` or `~lensdual.parametric.LenstoolModel`
        The parametric model. It is evaluated at the table's positions, which
        must be in the model's frame (for a Lenstool model: its model frame,
        see :meth:`~lensdual.parametric.LenstoolModel.to_model_frame`).
    z_source : float, optional
        Source redshift; required for a Lenstool model, ignored (must be None
        or equal) for a `ParametricFit`.
    snr_threshold : float
        A pair is anomalous when its SNR exceeds this (default 3).
    n_samples : int
        Parameter draws for ``mu_model_err`` of a `ParametricFit`.
    seed : int, `numpy.random.Generator` or None
        Seed of those draws.

    Returns
    -------
    table : `~astropy.table.QTable`
        ``pair_id``, ``mu_flux``, ``mu_flux_err``, ``mu_size``,
        ``mu_size_err``, ``mu_model``, ``mu_model_err``, ``ratio_size =
        mu_flux / mu_size``, ``snr_size``, ``anomalous_size``, ``ratio_model
        = mu_flux / mu_model``, ``snr_model``, ``anomalous_model`` (and
        ``mu_true`` when the input has it). The SNRs follow the ``"log"``
        definition of :func:`~lensdual.duality.check_duality`:
        :math:`|\ln R| / \sqrt{\sigma_{\ln F}^2 + \sigma_{\ln M}^2}`. A
        Lenstool model has no uncertainty here (``mu_model_err = 0``): its
        SNR counts the flux error only.
    """
    from .._pairs_table import positions as _positions
    from .._validation import as_positions
    from .lenstool import LenstoolModel

    if not isinstance(duality_table, Table):
        raise TypeError("duality_table must be an astropy Table (check_duality output), got "
                        f"{type(duality_table).__name__}")
    tab = QTable(duality_table, copy=False)
    need = ["mu_flux", "mu_flux_err", "mu_size", "mu_size_err"]
    missing = [c for c in need if c not in tab.colnames]
    if missing:
        raise ValueError(f"duality_table lacks the column(s) {missing}: pass the output of "
                         "check_duality")
    snr_threshold = as_real(snr_threshold, "snr_threshold", minimum=0.0)
    theta1, theta2 = _positions(tab)
    t1 = as_positions(theta1, "duality_table positions (x1, y1)")
    t2 = as_positions(theta2, "duality_table positions (x2, y2)")
    if isinstance(fit, ParametricFit):
        if z_source is not None and as_real(z_source, "z_source") != fit.z_source:
            raise ValueError(f"z_source={z_source} differs from the fit's z_source="
                             f"{fit.z_source}; leave it None for a ParametricFit")
        pred = fit.magnification_ratio(theta1, theta2, n_samples=n_samples, seed=seed)
        mu_model = np.asarray(pred["mu_model"], float)
        mu_model_err = np.asarray(pred["mu_model_err"], float)
        ln_model = _ln_err(pred, "mu_model")
    elif isinstance(fit, LenstoolModel):
        if z_source is None:
            raise ValueError("z_source is required to compare with a LenstoolModel")
        lm = fit.lens_model(as_real(z_source, "z_source"))
        with np.errstate(divide="ignore"):
            mu1 = np.asarray(lm.magnification(t1[:, 0], t1[:, 1]), float)
            mu2 = np.asarray(lm.magnification(t2[:, 0], t2[:, 1]), float)
        mu_model = np.abs(mu1 / mu2)
        mu_model_err = np.zeros_like(mu_model)
        ln_model = mu_model_err
    else:
        raise TypeError("fit must be a ParametricFit or a LenstoolModel, got "
                        f"{type(fit).__name__}")

    out = QTable()
    out["pair_id"] = (np.asarray(tab["pair_id"]) if "pair_id" in tab.colnames
                      else np.arange(1, len(tab) + 1))
    for c in need:
        out[c] = np.asarray(tab[c], dtype=float)
    out["mu_model"] = mu_model
    out["mu_model_err"] = mu_model_err
    if "mu_true" in tab.colnames:
        out["mu_true"] = np.asarray(tab["mu_true"], dtype=float)
    ln_flux = _ln_err(tab, "mu_flux")
    ln_size = _ln_err(tab, "mu_size")
    mu_flux = out["mu_flux"]
    with np.errstate(all="ignore"):
        for key, mu, ln in (("size", out["mu_size"], ln_size), ("model", mu_model, ln_model)):
            ratio = mu_flux / mu
            snr = np.abs(np.log(ratio)) / np.hypot(ln_flux, ln)
            out[f"ratio_{key}"] = ratio
            out[f"snr_{key}"] = snr
            out[f"anomalous_{key}"] = np.isfinite(snr) & (snr > snr_threshold)
    out.meta["snr_threshold"] = snr_threshold
    out.meta["model"] = (fit.model if isinstance(fit, ParametricFit)
                         else f"Lenstool model {getattr(fit, 'path', '')}")
    return out

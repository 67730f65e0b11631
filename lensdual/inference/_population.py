"""Sub-halo populations drawn near the images, with pyHalo's models (private).

pyHalo renders a population in a cone centred on the optical axis; cluster
arcs lie 20-30 arcsec from it, so a full cone holds tens of thousands of
haloes of which a handful matter. :class:`SubhaloPopulation` takes pyHalo's
mass function (its ``sigma_sub`` normalisation with the host-mass and
redshift scaling), concentration and truncation models, and places haloes
uniformly in a disc around each image.
"""

import math
import warnings

import numpy as np
from astropy import units as u
from astropy.utils.exceptions import AstropyDeprecationWarning

from .._validation import as_cosmology, as_real, as_redshifts

__all__ = ["SubhaloPopulation", "MODELS", "PYHALO_DEFAULT_SIGMA_SUB"]

#: pyHalo's default sigma_sub (kpc^-2): the demo's "cdm" population and the
#: orientation line of the inference figure.
PYHALO_DEFAULT_SIGMA_SUB = 0.025

#: Dark-matter models: ``"CDM"`` (pyHalo's ``CDM`` preset: power-law mass
#: function, LUDLOW2016 concentrations) and ``"WDM"`` (its ``WDM`` preset:
#: the SHMF_LOVELL2020 turnover of the mass function below the half-mode
#: mass and BOSE2016 concentrations).
MODELS = ("CDM", "WDM")

_M_PIVOT = 1e8  # pyHalo's pivot mass of sigma_sub [Msun]
_SCATTER = 0.2  # pyHalo's concentration scatter (the sigma of a natural-log normal)
_C_MIN = 1.2  # pyHalo's floor on concentrations
_N_GRID = 61  # masses at which the concentration-mass relation is tabulated


def _pyhalo():
    try:
        from pyHalo.concentration_models import preset_concentration_models
        from pyHalo.Cosmology.cosmology import Cosmology
        from pyHalo.Halos.tidal_truncation import TruncationRoche
        from pyHalo.mass_function_models import preset_mass_function_models
        from pyHalo.Rendering.MassFunctions.mass_function_base import WDMPowerLaw
        from pyHalo.Rendering.subhalos import host_scaling_function
    except ImportError as exc:  # pragma: no cover - the extra is part of the test install
        raise ImportError(
            "lensdual.inference needs pyHalo: pip install 'lensdual[halos]'"
        ) from exc
    return {
        "concentration": preset_concentration_models,
        "cosmology": Cosmology,
        "roche": TruncationRoche,
        "mass_function": preset_mass_function_models,
        "turnover": WDMPowerLaw._turnover,
        "host_scaling": host_scaling_function,
    }


class SubhaloPopulation:
    r"""A population of truncated-NFW sub-haloes in pyHalo's conventions.

    The projected number density per unit mass is pyHalo's

    .. math::

       \frac{d^2N}{dm\,dA} = \frac{\Sigma_{\rm sub}\,F(M_{\rm host}, z)}{m_0}
       \left(\frac{m}{m_0}\right)^{\alpha} T(m),
       \qquad m_0 = 10^8\,M_\odot,

    with ``sigma_sub`` = :math:`\Sigma_{\rm sub}` in kpc\ :sup:`-2`,
    :math:`F = 10^{k_1\log_{10}(M_{\rm host}/10^{13}) + k_2\log_{10}(z + 0.5)}`
    pyHalo's host scaling, :math:`\alpha` the slope and :math:`T` the WDM
    turnover (1 for CDM). Masses are M200 with respect to the critical
    density at ``z_lens``; concentrations follow pyHalo's model with its
    scatter; truncation radii follow pyHalo's Roche model,
    :math:`r_t = 1.4\,(m/10^7 M_\odot)^{1/3} (r_{3D}/50\,{\rm kpc})^{2/3}` kpc,
    with :math:`r_{3D}` drawn uniformly along the line of sight through the
    host's virial sphere.

    Parameters
    ----------
    z_lens, z_source : float
        Redshifts (``z_source > z_lens``).
    model : {"CDM", "WDM"}
        Dark-matter model (:data:`MODELS`).
    log_mlow, log_mhigh : float
        log10 of the mass range rendered [Msun]; default 6 and 10.
    log_m_host : float
        log10 of the host halo's mass [Msun]; default 15 (a cluster; pyHalo's
        galaxy-scale default is 13.3).
    shmf_log_slope : float
        :math:`\alpha`, default -1.9 (pyHalo's).
    log_mhm : float, optional
        log10 of the WDM half-mode mass [Msun]; required for ``"WDM"``.
    cosmology : `~astropy.cosmology.FLRW`, optional
        Default ``FlatLambdaCDM(H0=70, Om0=0.3)``.
    host_scaling_factor, redshift_scaling_factor : float
        :math:`k_1, k_2` of the host scaling; default 0.55 and 0.37, the
        values of pyHalo's CDM preset.
    host_centre : `~astropy.units.Quantity`, shape (2,)
        The host's centre in the lens frame (for :math:`r_{3D}`); default
        the origin.

    Raises
    ------
    ValueError
        Unknown model, an empty or inverted mass range, ``log_mhm`` missing
        for WDM, or a redshift out of order.
    """

    def __init__(self, z_lens, z_source, *, model="CDM", log_mlow=6.0, log_mhigh=10.0,
                 log_m_host=15.0, shmf_log_slope=-1.9, log_mhm=None, cosmology=None,
                 host_scaling_factor=0.55, redshift_scaling_factor=0.37,
                 host_centre=(0.0, 0.0) * u.arcsec):
        self.z_lens, self.z_source = as_redshifts(z_lens, z_source)
        if not isinstance(model, str) or model.upper() not in MODELS:
            raise ValueError(f"model must be one of {list(MODELS)}, got {model!r}")
        self.model = model.upper()
        self.log_mlow = as_real(log_mlow, "log_mlow")
        self.log_mhigh = as_real(log_mhigh, "log_mhigh")
        if not self.log_mhigh > self.log_mlow:
            raise ValueError(f"log_mhigh ({log_mhigh}) must exceed log_mlow ({log_mlow})")
        self.log_m_host = as_real(log_m_host, "log_m_host", minimum=8.0, maximum=16.5)
        self.shmf_log_slope = as_real(shmf_log_slope, "shmf_log_slope", minimum=-3.0,
                                      maximum=-1.01)
        if self.model == "WDM":
            if log_mhm is None:
                raise ValueError("model='WDM' needs log_mhm, the log10 half-mode mass [Msun]")
            self.log_mhm = as_real(log_mhm, "log_mhm", minimum=4.0, maximum=12.0)
        else:
            if log_mhm is not None:
                raise ValueError("log_mhm is a WDM parameter; use model='WDM' with it")
            self.log_mhm = None
        self.cosmology = as_cosmology(cosmology)
        self.host_scaling_factor = as_real(host_scaling_factor, "host_scaling_factor")
        self.redshift_scaling_factor = as_real(redshift_scaling_factor, "redshift_scaling_factor")
        c = u.Quantity(host_centre, u.arcsec).value
        if np.shape(c) != (2,) or not np.isfinite(c).all():
            raise ValueError(f"host_centre must be a finite (x, y) angle, got {host_centre!r}")
        self.host_centre = np.asarray(c, dtype=float)
        self._setup()

    def __repr__(self):
        extra = f", log_mhm={self.log_mhm}" if self.model == "WDM" else ""
        return (f"SubhaloPopulation(model={self.model!r}, z_lens={self.z_lens}, "
                f"z_source={self.z_source}, log_m=[{self.log_mlow}, {self.log_mhigh}], "
                f"log_m_host={self.log_m_host}{extra})")

    # ------------------------------------------------------------------ setup

    def _setup(self):
        from lenstronomy.Cosmo.lens_cosmo import LensCosmo

        ph = _pyhalo()
        cosmo = self.cosmology
        kwargs_cosmo = {"H0": float(cosmo.H0.value), "Om0": float(cosmo.Om0)}
        if cosmo.Ob0 is not None and cosmo.Ob0 > 0:
            kwargs_cosmo["Ob0"] = float(cosmo.Ob0)
        with warnings.catch_warnings():
            # pyHalo 1.4.5 calls astropy's deprecated angular_diameter_distance_z1z2
            warnings.simplefilter("ignore", AstropyDeprecationWarning)
            ph["cosmology"](astropy_instance=cosmo, cosmo_kwargs=kwargs_cosmo)
        self._kpc_per_arcsec = float(cosmo.kpc_proper_per_arcmin(self.z_lens).to_value(
            u.kpc / u.arcsec))
        self._lens_cosmo = LensCosmo(z_lens=self.z_lens, z_source=self.z_source, cosmo=cosmo)
        self._host_scaling = float(ph["host_scaling"](10**self.log_m_host, self.z_lens,
                                                      self.host_scaling_factor,
                                                      self.redshift_scaling_factor))
        if self.model == "CDM":
            cls, kw = ph["concentration"]("LUDLOW2016", {"cosmo": cosmo})
            self._turnover_kwargs = None
        else:
            cls, kw = ph["concentration"]("BOSE2016", {"cosmo": cosmo, "log_mc": self.log_mhm})
            _, tk = ph["mass_function"]("SHMF_LOVELL2020")
            self._turnover_kwargs = (tk["a_wdm"], tk["b_wdm"], tk["c_wdm"])
        kw = dict(kw)
        kw["scatter"] = False
        conc = cls(**kw)
        self._log_m_grid = np.linspace(self.log_mlow, self.log_mhigh, _N_GRID)
        c = np.asarray(conc.nfw_concentration(10**self._log_m_grid, self.z_lens), dtype=float)
        self._log_c_grid = np.log(np.maximum(c, _C_MIN))
        self._turnover = ph["turnover"]
        self._roche = ph["roche"]()
        rho_c = cosmo.critical_density(self.z_lens).to_value(u.Msun / u.kpc**3)
        self._r200_host_kpc = float((3 * 10**self.log_m_host / (4 * math.pi * 200 * rho_c))
                                    ** (1 / 3))

    # ------------------------------------------------------------------ numbers

    def _unbroken_density(self, sigma_sub):
        """Haloes per arcsec^2 of the power law (before any WDM turnover)."""
        a = self.shmf_log_slope
        lo, hi = 10**self.log_mlow, 10**self.log_mhigh
        integral = _M_PIVOT ** -(a + 1) * (hi ** (a + 1) - lo ** (a + 1)) / (a + 1)
        return sigma_sub * self._host_scaling * integral * self._kpc_per_arcsec**2

    def _turnover_factor(self, m):
        if self._turnover_kwargs is None:
            return np.ones_like(m)
        a, b, c = self._turnover_kwargs
        return self._turnover(m, self.log_mhm, a, b, c)

    def number_density(self, sigma_sub):
        """Expected number of haloes per arcsec^2 in the lens plane.

        Parameters
        ----------
        sigma_sub : `~astropy.units.Quantity`
            Abundance in kpc^-2 (pyHalo's ``sigma_sub``), scalar.

        Returns
        -------
        density : `~astropy.units.Quantity`
            In arcsec^-2.
        """
        s = _as_sigma_sub(sigma_sub)
        n = self._unbroken_density(s)
        if self._turnover_kwargs is not None:
            lm = np.linspace(self.log_mlow, self.log_mhigh, 2001)
            m = 10**lm
            w = m ** (self.shmf_log_slope + 1)
            n *= float(np.trapezoid(w * self._turnover_factor(m), lm) / np.trapezoid(w, lm))
        return n / u.arcsec**2

    # ------------------------------------------------------------------ draws

    def _mass_quantiles(self, q):
        """Masses at quantiles ``q`` of the power law (its inverse CDF)."""
        a1 = self.shmf_log_slope + 1
        lo, hi = 10 ** (a1 * self.log_mlow), 10 ** (a1 * self.log_mhigh)
        return (lo + q * (hi - lo)) ** (1 / a1)

    def _masses(self, rng, n):
        return self._mass_quantiles(rng.random(n))

    def _parameters(self, rng, m, r2d_kpc):
        """Angular tNFW parameters (Rs, alpha_Rs, r_trunc) [arcsec] of masses ``m``."""
        return self._parameters_at(m, r2d_kpc, rng.standard_normal(m.size),
                                   2 * rng.random(m.size) - 1)

    def _parameters_at(self, m, r2d_kpc, scatter, los):
        """:meth:`_parameters` for given normal deviates of the concentration and
        line-of-sight fractions in [-1, 1] of the host's virial sphere."""
        log_c = np.interp(np.log10(m), self._log_m_grid, self._log_c_grid)
        c = np.maximum(np.exp(log_c + _SCATTER * scatter), _C_MIN)
        rs, alpha_rs = self._lens_cosmo.nfw_physical2angle(M=m, c=c)
        half = np.sqrt(np.maximum(self._r200_host_kpc**2 - r2d_kpc**2, 0.0))
        r3d = np.maximum(np.hypot(r2d_kpc, los * half), 1e-3)
        rt = np.asarray(self._roche.truncation_radius(m, r3d), dtype=float)
        rt = np.maximum(rt, 1e-6) / self._kpc_per_arcsec
        return np.asarray(rs, float), np.asarray(alpha_rs, float), rt

    def _quadrature(self, r2d_kpc, n_mass=400, n_scatter=5, n_los=8):
        """Nodes and weights of an average over the population at projected radius
        ``r2d_kpc``: mass quantiles (midpoints), Gauss-Hermite concentration
        scatter, midpoints along the line of sight; weights include the WDM
        turnover (normalised to the unbroken power law)."""
        m = self._mass_quantiles((np.arange(n_mass) + 0.5) / n_mass)
        x, w = np.polynomial.hermite_e.hermegauss(n_scatter)
        w = w / w.sum()
        los = (np.arange(n_los) + 0.5) / n_los * 2 - 1
        mm, zz, ll = np.meshgrid(m, x, los, indexing="ij")
        ww = np.broadcast_to(w[None, :, None], mm.shape) / (n_mass * n_los)
        mm, zz, ll, ww = (a.ravel() for a in (mm, zz, ll, ww))
        ww = ww * self._turnover_factor(mm)
        return self._parameters_at(mm, np.full(mm.size, r2d_kpc), zz, ll), ww

    def draw(self, rng, sigma_sub, centre, radius):
        """Sub-haloes in a disc of the lens plane.

        Parameters
        ----------
        rng : `numpy.random.Generator`
        sigma_sub : float
            Abundance [kpc^-2].
        centre : (2,) float
            Disc centre, arcsec (lens frame).
        radius : float
            Disc radius, arcsec.

        Returns
        -------
        halos : dict of ndarray
            ``x``, ``y`` (arcsec, lens frame), ``mass`` [Msun], ``rs``,
            ``alpha_rs``, ``r_trunc`` (arcsec).
        """
        lam = self._unbroken_density(sigma_sub) * math.pi * radius**2
        n = int(rng.poisson(lam))
        m = self._masses(rng, n)
        if self._turnover_kwargs is not None and n:
            m = m[rng.random(n) < self._turnover_factor(m)]
            n = m.size
        r = radius * np.sqrt(rng.random(n))
        phi = 2 * math.pi * rng.random(n)
        x = centre[0] + r * np.cos(phi)
        y = centre[1] + r * np.sin(phi)
        r2d = np.hypot(x - self.host_centre[0], y - self.host_centre[1]) * self._kpc_per_arcsec
        rs, alpha_rs, rt = self._parameters(rng, m, r2d)
        return {"x": x, "y": y, "mass": m, "rs": rs, "alpha_rs": alpha_rs, "r_trunc": rt}


def _kpc2_values(value, name):
    """An abundance Quantity's values in kpc^-2 (float array), or TypeError naming it."""
    if not isinstance(value, u.Quantity):
        raise TypeError(f"{name} must be a Quantity in kpc^-2 (e.g. 0.025 / u.kpc**2), "
                        f"got {type(value).__name__}")
    try:
        return np.asarray(value.to_value(u.kpc**-2), dtype=float)
    except u.UnitConversionError:
        raise TypeError(f"{name} must be a number per area (kpc^-2), got unit {value.unit}") \
            from None


def _as_sigma_sub(value, name="sigma_sub", *, positive=False):
    """A scalar abundance Quantity in kpc^-2 as a float >= 0 (> 0 if ``positive``)."""
    v = _kpc2_values(value, name)
    if v.ndim != 0 or not np.isfinite(v) or v < 0 or (positive and v == 0):
        cond = "> 0" if positive else ">= 0"
        raise ValueError(f"{name} must be a finite scalar {cond}, got {value}")
    return float(v)

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
_LOS_TRUNCATION = 50.0  # pyHalo's TRUNCATION_RN: field haloes end at r_50 (50 rho_crit(z))
_LOS_TURNOVER = (1.95, 0.8, -1.0)  # pyHalo's LOVELL2020 turnover of field haloes (WDM preset)
_LOS_FIT_MASSES = 10  # masses of pyHalo's power-law fit to the Sheth-Tormen function


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


def _pyhalo_los():
    from pyHalo.concentration_models import ConcentrationDiemerJoyce
    from pyHalo.Halos.lens_cosmo import LensCosmo
    from pyHalo.Rendering.MassFunctions.density_peaks import evaluate_mass_function
    from pyHalo.Rendering.two_halo import two_halo_enhancement_factor
    from pyHalo.utilities import generate_lens_plane_redshifts
    return {
        "planes": generate_lens_plane_redshifts,
        "sheth_tormen": evaluate_mass_function,
        "two_halo": two_halo_enhancement_factor,
        "lens_cosmo": LensCosmo,
        "host_concentration": ConcentrationDiemerJoyce,
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
    los_normalization : float
        pyHalo's ``LOS_normalization``: line-of-sight haloes at this multiple
        of its field-halo mass function; default 0, none (pyHalo's own
        default is 1). See the notes.
    two_halo : bool
        With line-of-sight haloes, add pyHalo's two-halo term (correlated
        structure in the lens plane, outside the host); default True, as
        pyHalo does.

    Notes
    -----
    Line-of-sight haloes follow pyHalo's ``LINE_OF_SIGHT`` rendering: planes
    every 0.02 in redshift from 0.01 to the source (one at ``z_lens``), in
    each the power law that pyHalo fits to the Sheth-Tormen mass function
    (colossus) over the mass range, times ``los_normalization`` and the
    comoving volume; concentrations from the model's relation at the
    plane's redshift with the same scatter; truncation at
    :math:`r_{50}` (pyHalo's ``TRUNCATION_RN``); for WDM, pyHalo's
    ``LOVELL2020`` turnover of field haloes. They are drawn uniformly in a
    disc of the plane's angles around each image's ray, and do not scale
    with ``sigma_sub``. Each plane's mean convergence is removed as a sheet:
    lensdual removes the mean of all its haloes (the two-halo ones and every
    mass included), because the mean is part of the smooth field that the
    constellation measures; pyHalo removes that of its ``LINE_OF_SIGHT``
    haloes above 1e7 Msun only. Behind the lens the density is the one per
    unit angle of the plane, 3-5 % above pyHalo's double cone, whose radius
    shrinks within a slab.

    Raises
    ------
    ValueError
        Unknown model, an empty or inverted mass range, ``log_mhm`` missing
        for WDM, or a redshift out of order.
    """

    def __init__(self, z_lens, z_source, *, model="CDM", log_mlow=6.0, log_mhigh=10.0,
                 log_m_host=15.0, shmf_log_slope=-1.9, log_mhm=None, cosmology=None,
                 host_scaling_factor=0.55, redshift_scaling_factor=0.37,
                 host_centre=(0.0, 0.0) * u.arcsec, los_normalization=0.0, two_halo=True):
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
        self.los_normalization = as_real(los_normalization, "los_normalization", minimum=0.0)
        if not isinstance(two_halo, (bool, np.bool_)):
            raise TypeError(f"two_halo must be True or False, got {two_halo!r}")
        self.two_halo = bool(two_halo)
        self._setup()

    def _arguments(self):
        """The constructor's arguments that build this population again (a dict)."""
        return {"z_lens": self.z_lens, "z_source": self.z_source, "model": self.model,
                "log_mlow": self.log_mlow, "log_mhigh": self.log_mhigh,
                "log_m_host": self.log_m_host, "shmf_log_slope": self.shmf_log_slope,
                "log_mhm": self.log_mhm, "cosmology": self.cosmology,
                "host_scaling_factor": self.host_scaling_factor,
                "redshift_scaling_factor": self.redshift_scaling_factor,
                "host_centre": self.host_centre * u.arcsec,
                "los_normalization": self.los_normalization, "two_halo": self.two_halo}

    def _settings(self, leave_out=()):
        """Every setting of the population but those named in ``leave_out``, as a
        hashable tuple (equal tuples: the same population)."""
        out = []
        for name, value in self._arguments().items():
            if name in leave_out:
                continue
            if name == "cosmology":
                value = repr(value)
            elif name == "host_centre":
                value = tuple(float(c) for c in value.value)
            out.append((name, value))
        return tuple(out)

    def __repr__(self):
        extra = f", log_mhm={self.log_mhm}" if self.model == "WDM" else ""
        if self.los_normalization > 0:
            extra += f", los_normalization={self.los_normalization}"
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
            ph_cosmology = ph["cosmology"](astropy_instance=cosmo, cosmo_kwargs=kwargs_cosmo)
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
        self._los = None
        if self.los_normalization > 0:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", AstropyDeprecationWarning)
                self._los = self._setup_los(ph, ph_cosmology, cls, kw)

    def _setup_los(self, ph, ph_cosmology, conc_cls, conc_kwargs):
        """Per-plane tables of the line-of-sight haloes (see the class notes)."""
        from lenstronomy.Cosmo.lens_cosmo import LensCosmo

        los = _pyhalo_los()
        cosmo = self.cosmology
        _ = ph_cosmology.colossus  # sets colossus's cosmology for the mass function
        z, dz = (np.asarray(v, dtype=float) for v in los["planes"](self.z_lens, self.z_source))
        keep = (z > 0) & (z < self.z_source)
        z, dz = z[keep], dz[keep]
        h = float(cosmo.h)
        m_fit = np.logspace(self.log_mlow, self.log_mhigh, _LOS_FIT_MASSES)
        lo, hi = 10**self.log_mlow, 10**self.log_mhigh
        arcsec = math.pi / 180 / 3600
        x, w = np.polynomial.legendre.leggauss(8)
        slope = np.empty(z.size)
        density = np.empty(z.size)
        for j in range(z.size):
            dn = np.asarray(los["sheth_tormen"](m_fit, h, z[j], "sheth99"), dtype=float)
            coef = np.polyfit(np.log10(m_fit / _M_PIVOT), np.log10(dn), 1)
            a = coef[0]
            norm = 10 ** coef[1] / _M_PIVOT**a  # dN/dm/dV = norm m^a [Mpc^-3 Msun^-1]
            per_volume = norm * (hi ** (a + 1) - lo ** (a + 1)) / (a + 1)
            zz = z[j] + 0.5 * dz[j] * (x + 1)
            dm = cosmo.comoving_transverse_distance(zz).to_value(u.Mpc)
            dh = cosmo.hubble_distance.to_value(u.Mpc) / cosmo.efunc(zz)
            volume = 0.5 * dz[j] * float(np.sum(w * dm**2 * dh)) * arcsec**2  # Mpc^3 / arcsec^2
            slope[j] = a
            density[j] = self.los_normalization * per_volume * volume
        at_lens = int(np.argmin(np.abs(z - self.z_lens)))
        if self.two_halo:
            # the boost does not depend on the source (pyHalo's LensCosmo with a source
            # beyond its distance tables, z > 4, would fail)
            lc = los["lens_cosmo"](self.z_lens, None, ph_cosmology)
            c_host = los["host_concentration"](cosmo, scatter=False).nfw_concentration(
                10**self.log_m_host, self.z_lens)
            _, _, r200 = lc.NFW_params_physical(10**self.log_m_host, c_host, self.z_lens)
            boost = los["two_halo"](self.z_lens, dz[at_lens], lc, 10**self.log_m_host,
                                    r200 * 1e-3, True, 1.0)
            density[at_lens] *= 1.0 + float(boost)
        conc = conc_cls(**conc_kwargs)
        log_c = np.empty((z.size, self._log_m_grid.size))
        for j in range(z.size):
            c = np.asarray(conc.nfw_concentration(10**self._log_m_grid, z[j]), dtype=float)
            log_c[j] = np.log(np.maximum(c, _C_MIN))
        rho_c = cosmo.critical_density(z).to_value(u.Msun / u.kpc**3)
        kpc_per_arcsec = cosmo.kpc_proper_per_arcmin(z).to_value(u.kpc / u.arcsec)
        rt_coef = (3 / (4 * math.pi * _LOS_TRUNCATION * rho_c)) ** (1 / 3) / kpc_per_arcsec
        d_s = cosmo.angular_diameter_distance(self.z_source).to_value(u.Mpc)
        d_l = cosmo.angular_diameter_distance(self.z_lens).to_value(u.Mpc)
        beta = np.zeros(z.size)
        for j in range(z.size):
            d_j = cosmo.angular_diameter_distance(z[j]).to_value(u.Mpc)
            if z[j] < self.z_lens:
                d_jl = cosmo.angular_diameter_distance(z[j], self.z_lens).to_value(u.Mpc)
                d_js = cosmo.angular_diameter_distance(z[j], self.z_source).to_value(u.Mpc)
                beta[j] = d_jl * d_s / (d_l * d_js)
            elif z[j] > self.z_lens:
                d_lj = cosmo.angular_diameter_distance(self.z_lens, z[j]).to_value(u.Mpc)
                d_ls = cosmo.angular_diameter_distance(self.z_lens,
                                                            self.z_source).to_value(u.Mpc)
                beta[j] = d_lj * d_s / (d_j * d_ls)
        return {
            "z": z, "slope": slope, "density": density, "log_c": log_c, "rt_coef": rt_coef,
            "beta": beta, "front": z < self.z_lens,
            "cosmo": [LensCosmo(z_lens=float(zj), z_source=self.z_source, cosmo=cosmo)
                      for zj in z],
        }

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

    def _mass_quantiles(self, q, slope=None):
        """Masses at quantiles ``q`` of the power law (its inverse CDF) over the mass
        range; ``slope`` (scalar or per quantile) defaults to the sub-haloes'."""
        a1 = (self.shmf_log_slope if slope is None else slope) + 1
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

    def _los_turnover(self, m):
        if self._turnover_kwargs is None:
            return np.ones_like(m)
        return self._turnover(m, self.log_mhm, *_LOS_TURNOVER)

    def _los_parameters(self, plane, m, scatter):
        """Angular tNFW parameters (Rs, alpha_Rs, r_trunc) [arcsec] of line-of-sight
        haloes of masses ``m`` in planes ``plane`` (sorted), for normal deviates
        ``scatter`` of their concentrations."""
        los = self._los
        t = (np.log10(m) - self.log_mlow) / (self.log_mhigh - self.log_mlow) * (_N_GRID - 1)
        i = np.clip(np.floor(t).astype(int), 0, _N_GRID - 2)
        f = t - i
        log_c = los["log_c"][plane, i] * (1 - f) + los["log_c"][plane, i + 1] * f
        c = np.maximum(np.exp(log_c + _SCATTER * scatter), _C_MIN)
        rt = los["rt_coef"][plane] * m ** (1 / 3)
        rs = np.empty(m.size)
        alpha_rs = np.empty(m.size)
        bounds = np.searchsorted(plane, np.arange(los["z"].size + 1))
        for j in np.flatnonzero(np.diff(bounds)):
            sl = slice(bounds[j], bounds[j + 1])
            rs[sl], alpha_rs[sl] = los["cosmo"][j].nfw_physical2angle(M=m[sl], c=c[sl])
        return rs, alpha_rs, rt

    def _los_draw(self, rng, radius, n_real):
        """Line-of-sight haloes of ``n_real`` realisations in discs of radius ``radius``
        (arcsec) around a ray, every plane: dict of arrays ``x, y`` (the plane's angles
        from the ray), ``plane``, ``real`` (realisation), ``mass``, ``rs``,
        ``alpha_rs``, ``r_trunc``."""
        los = self._los
        n_planes = los["z"].size
        counts = rng.poisson(los["density"][:, None] * math.pi * radius**2,
                             size=(n_planes, n_real))
        plane = np.repeat(np.arange(n_planes), counts.sum(axis=1))
        real = np.repeat(np.tile(np.arange(n_real), n_planes), counts.ravel())
        m = self._mass_quantiles(rng.random(plane.size), los["slope"][plane])
        scatter = rng.standard_normal(plane.size)
        r = radius * np.sqrt(rng.random(plane.size))
        phi = 2 * math.pi * rng.random(plane.size)
        if self._turnover_kwargs is not None:
            keep = rng.random(plane.size) < self._los_turnover(m)
            plane, real, m, scatter, r, phi = (v[keep] for v in (plane, real, m, scatter, r,
                                                                  phi))
        rs, alpha_rs, rt = self._los_parameters(plane, m, scatter)
        return {"x": r * np.cos(phi), "y": r * np.sin(phi), "plane": plane, "real": real,
                "mass": m, "rs": rs, "alpha_rs": alpha_rs, "r_trunc": rt}

    def _los_quadrature(self, n_mass=100, n_scatter=5):
        """Nodes (plane, (Rs, alpha_Rs, r_trunc)) and weights of the average over each
        plane's line-of-sight haloes, turnover included (normalised per plane to the
        unbroken power law)."""
        los = self._los
        q = (np.arange(n_mass) + 0.5) / n_mass
        x, w = np.polynomial.hermite_e.hermegauss(n_scatter)
        w = w / w.sum()
        plane = np.repeat(np.arange(los["z"].size), n_mass * n_scatter)
        m = self._mass_quantiles(np.tile(np.repeat(q, n_scatter), los["z"].size),
                                 los["slope"][plane])
        scatter = np.tile(x, los["z"].size * n_mass)
        weight = np.tile(w, los["z"].size * n_mass) / n_mass * self._los_turnover(m)
        return plane, self._los_parameters(plane, m, scatter), weight

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

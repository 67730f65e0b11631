"""Parametric lens models: Lenstool model files and lenstronomy fits.

:func:`read_lenstool` reads a Lenstool ``best.par`` of dPIE potentials
(profile 81) into a :class:`LenstoolModel`, evaluated by Numba kernels through
a lenstronomy-like :class:`DPIELensModel`; :func:`read_lenstool_images` reads
the multiple-image catalogue the model was fitted to.
:func:`fit_parametric_lens` fits a lenstronomy model to a constellation and
:func:`compare_with_parametric` puts model magnification ratios beside
``mu_size`` and ``mu_flux``.
"""

from .fitting import *  # noqa: F403
from .fitting import __all__ as _fitting_all
from .lenstool import *  # noqa: F403
from .lenstool import __all__ as _lenstool_all

__all__ = _lenstool_all + _fitting_all

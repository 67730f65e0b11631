"""Parametric lens models: Lenstool model files and lenstronomy fits.

:func:`read_lenstool` reads a Lenstool ``best.par`` of dPIE (profile 81) and
NFW (profile 12) potentials into a :class:`LenstoolModel`, evaluated by Numba
kernels through a lenstronomy-like :class:`LenstoolLensModel`;
:func:`read_lenstool_images` reads the multiple-image catalogue the model was
fitted to. :func:`fit_parametric_lens` fits a lenstronomy model to a
constellation and :func:`compare_with_parametric` puts model magnification
ratios beside ``mu_size`` and ``mu_flux``; :func:`parametric_comparison` does
both for a duality-checked pairs table in one call.
:func:`compare_size_with_models` puts the size magnification of a
position-only (knot) constellation beside one or several models' ratios.
"""

from .comparison import *  # noqa: F403
from .comparison import __all__ as _comparison_all
from .fitting import *  # noqa: F403
from .fitting import __all__ as _fitting_all
from .knots import *  # noqa: F403
from .knots import __all__ as _knots_all
from .lenstool import *  # noqa: F403
from .lenstool import __all__ as _lenstool_all

__all__ = _lenstool_all + _fitting_all + _comparison_all + _knots_all

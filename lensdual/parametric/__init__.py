"""Parametric lens models: Lenstool model files (and, later, lenstronomy fits).

:func:`read_lenstool` reads a Lenstool ``best.par`` of dPIE potentials
(profile 81) into a :class:`LenstoolModel`, evaluated by Numba kernels through
a lenstronomy-like :class:`DPIELensModel`; :func:`read_lenstool_images` reads
the multiple-image catalogue the model was fitted to.
"""

from .lenstool import *  # noqa: F403
from .lenstool import __all__  # noqa: F401

"""Model-independent estimators of the relative Jacobian and size magnification.

The 2v and Quad (QW) Jacobians of the paper's Sect. 4 and a second-order
Quad variant, with bootstrap errors from positional uncertainty, and the
locality-adaptive estimator (the default), whose analytic errors include
its own truncation error.

``METHODS`` maps each estimator name accepted by :func:`relative_jacobian`
and :func:`size_magnification` (``"adaptive"``, the default, ``"quad"``,
``"2v"``, ``"quad2"``) to the smallest number of pairs it needs.

The modules: ``core`` (the public functions: validation, units, tables),
``_kernels`` (Numba kernels of the paper's estimators), ``_adaptive`` (the
adaptive estimator's kernels and its ``AdaptiveSettings``) and ``_linalg``
(the small solvers they share).

Adding an estimator:

1. give it a name and its smallest number of pairs in ``METHODS``, and a
   method code that ``core`` passes to its kernel;
2. write the kernel (unit-free ``float64`` arrays in, no validation) in
   ``_kernels.py``, or in a module of its own when it carries settings or
   state of its own, as ``_adaptive.py`` does;
3. write its plain-numpy twin in ``tests/_reference.py`` and a test that
   kernel and twin agree on random constellations;
4. run the calibration suite (``benchmarks/calibration.py``) and report its
   pulls, false flags and power before it becomes anyone's default.
"""

from .core import *  # noqa: F403
from .core import __all__  # noqa: F401

"""Model-independent estimators of the relative Jacobian and size magnification.

The 2v and Quad (QW) Jacobians of the paper's Sect. 4, a second-order Quad
variant, and bootstrap errors from positional uncertainty.

``METHODS`` maps each estimator name accepted by :func:`relative_jacobian`
and :func:`size_magnification` (``"quad"``, ``"2v"``, ``"quad2"``) to the
smallest number of pairs it needs.
"""

from .core import *  # noqa: F403
from .core import __all__  # noqa: F401

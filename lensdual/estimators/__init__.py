"""Model-independent estimators of the relative Jacobian and size magnification.

The 2v and Quad (QW) Jacobians of the paper's Sect. 4, a second-order Quad
variant, and bootstrap errors from positional uncertainty.
"""

from .core import *  # noqa: F403
from .core import __all__  # noqa: F401

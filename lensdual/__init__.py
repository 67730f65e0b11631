"""lensdual: model-independent sub-structure detection with geometrical duality.

Multiply-imaged constellations of compact star clusters measure the local
relative Jacobian between two lens arcs without a lens model; its determinant,
the size magnification, must equal the flux ratio of every point-source pair
(geometrical duality). Pairs that break duality point at dark sub-haloes.
"""

try:
    from ._version import version as __version__
except ImportError:  # pragma: no cover - only in a source tree without a build
    __version__ = "0.0.0"

from .duality import check_duality
from .estimators import relative_jacobian, size_magnification

__all__ = ["__version__", "check_duality", "relative_jacobian", "size_magnification"]

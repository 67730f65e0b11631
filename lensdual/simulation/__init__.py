"""Lens simulations on lenstronomy: the truth machine of lensdual.

Lens systems built from physical parameters (truncated NFW haloes, cluster
members, sub-haloes), exact image finding for point-source constellations,
the SMACS0723 analogue of the paper's Table 1, and clean constellations from
several lens families for calibrating the estimators.
"""

from .families import *  # noqa: F403
from .families import __all__ as _families_all
from .halos import *  # noqa: F403
from .halos import __all__ as _halos_all
from .lens_system import *  # noqa: F403
from .lens_system import __all__ as _system_all
from .mock import *  # noqa: F403
from .mock import __all__ as _mock_all
from .scenarios import *  # noqa: F403
from .scenarios import __all__ as _scenarios_all

__all__ = _halos_all + _system_all + _scenarios_all + _mock_all + _families_all

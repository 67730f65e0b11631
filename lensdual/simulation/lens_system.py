"""A lens system: lenstronomy profiles, redshifts and a cosmology, with units.

`LensSystem` lives in ``lensdual._lens.system``, below both
`lensdual.simulation` and `lensdual.parametric` (a Lenstool model builds one);
this module keeps its import path.
"""

from .._lens.system import LensSystem

__all__ = ["LensSystem"]

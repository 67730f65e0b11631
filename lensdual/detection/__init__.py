"""Point-source candidates on lens arcs (the paper's Appendix C).

:class:`PointSourceFilter` runs the paper's filter chain on one or several
bands of a lens-arc image and returns a :class:`PointSourceMap` (the
candidate map and its ingredients); :func:`find_point_sources` segments the
candidate map into a catalogue of point sources with photutils.
"""

from .core import *  # noqa: F403
from .core import __all__  # noqa: F401

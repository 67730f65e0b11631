from . import _core
from ._core import *  # noqa: F403
from ._core import __all__  # noqa: F401

__doc__ = _core.__doc__

"""One lens profile: a lenstronomy profile name and its keyword arguments."""

from dataclasses import dataclass, field

__all__ = ["LensComponent"]


@dataclass(frozen=True)
class LensComponent:
    """One lens profile: a lenstronomy profile name and its keyword arguments.

    Parameters
    ----------
    profile : str
        lenstronomy profile name (e.g. ``"TNFW"``).
    kwargs : dict
        Its keyword arguments, angles in arcsec.
    label : str
        A name for the component (``"main halo"``, ``"member 1"``, ...).
    meta : dict
        The physical parameters it was built from (mass, concentration, ...).
    """

    profile: str
    kwargs: dict
    label: str = ""
    meta: dict = field(default_factory=dict)

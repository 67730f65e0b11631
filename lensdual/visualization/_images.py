"""The pairs drawn on the images of both arcs."""

import numpy as np

from ._common import _plt
from ._duality import plot_pairing_map

__all__ = ["plot_arc_images"]


def _north_up(ccd):
    """``ccd`` (data, wcs) with north up and east left: reprojected when the pixel grid
    is rotated and ``reproject`` is installed, else as stored (with a note)."""
    import warnings

    from ..exceptions import LensdualWarning

    wcs = ccd.wcs.celestial
    pc = wcs.wcs.get_pc() * wcs.wcs.get_cdelt()[:, None]
    angle = np.degrees(np.arctan2(pc[1, 0], pc[1, 1]))  # rotation of the y axis from north
    if abs(angle) < 0.5 and pc[0, 0] < 0:
        return np.asarray(ccd.data, dtype=float), wcs, True
    try:
        from reproject import reproject_interp
    except ImportError:
        warnings.warn("the image is not north-up and reproject is not installed: it is "
                      "drawn as stored, with a compass (pip install reproject)",
                      LensdualWarning, stacklevel=3)
        return np.asarray(ccd.data, dtype=float), wcs, False
    from astropy.wcs import WCS

    scale = np.sqrt(abs(np.linalg.det(pc)))
    ny, nx = ccd.data.shape
    centre = wcs.pixel_to_world((nx - 1) / 2, (ny - 1) / 2)
    target = WCS(naxis=2)
    target.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    target.wcs.crval = [centre.ra.deg, centre.dec.deg]
    size = int(np.ceil(np.hypot(nx, ny)))
    target.wcs.crpix = [(size + 1) / 2, (size + 1) / 2]
    target.wcs.cdelt = [-scale, scale]
    data, _ = reproject_interp((np.asarray(ccd.data, dtype=float), wcs), target,
                               shape_out=(size, size))
    return data, target, True


def plot_arc_images(images, result, *, band=None, fig=None, margin=0.4, scale_bar=1.0,
                    mapped=True):
    """The paper's Fig. 3 as astronomers draw it: both arcs' images with numbered pairs.

    Each arc is drawn on `~astropy.visualization.wcsaxes.WCSAxes` (RA/Dec
    grid), north up and east left (reprojected with ``reproject`` when the
    image is rotated), cut out around its pairs, with an arcsec scale bar and
    a numbered circle on every pair: red for ``anomalous``, yellow for
    untested, green otherwise. With ``mapped`` a third panel shows the
    mapped view of :func:`plot_pairing_map`.

    Parameters
    ----------
    images : dict
        ``{"L1": CCDData or {band: CCDData}, "L2": ...}`` with celestial WCS.
    result : `~astropy.table.Table`
        A pairs table with SkyCoord ``sky1``, ``sky2`` (e.g. the output of
        :func:`~lensdual.duality.check_duality` on measured pairs).
    band : str, optional
        Which band to draw (default the first).
    fig : `matplotlib.figure.Figure`, optional
    margin : float
        Margin around the pairs, arcsec (default 0.4).
    scale_bar : float
        Length of the scale bar, arcsec (default 1).
    mapped : bool
        Add the mapped view as a third panel (default True).

    Returns
    -------
    fig : `matplotlib.figure.Figure`
    """
    from astropy.coordinates import SkyCoord
    from astropy.nddata import Cutout2D
    from astropy.visualization import AsinhStretch, ImageNormalize, PercentileInterval

    from .._pairs_table import SKY_COLUMNS, sky_col

    plt = _plt()
    for col in SKY_COLUMNS:
        if col not in result.colnames or not isinstance(result[col], SkyCoord):
            raise ValueError(f"result needs a SkyCoord column {col!r}")
    from matplotlib import patheffects

    # a dark outline keeps the pair markers readable on bright and dark pixels
    outline = (patheffects.withStroke(linewidth=2.5, foreground="black"),)
    n_panels = 3 if mapped else 2
    if fig is None:
        fig = plt.figure(figsize=(5.0 * n_panels, 5.0))
    ids = result["pair_id"] if "pair_id" in result.colnames else range(1, len(result) + 1)
    colour = np.array(["lime"] * len(result), dtype=object)
    if "tested" in result.colnames:
        colour[~np.asarray(result["tested"], bool)] = "yellow"
    if "anomalous" in result.colnames:
        colour[np.asarray(result["anomalous"], bool)] = "red"
    for k, arc in enumerate(("L1", "L2")):
        img = images[arc]
        if isinstance(img, dict):
            img = img[band if band is not None else next(iter(img))]
        data, wcs, north = _north_up(img)
        sky = result[sky_col(arc)]
        px, py = wcs.world_to_pixel(sky)
        finite = np.isfinite(px) & np.isfinite(py)
        if not finite.any():
            raise ValueError(f"no pair has a finite position on arc {arc}")
        px, py = px[finite], py[finite]
        scale = float(np.sqrt(abs(np.linalg.det(wcs.pixel_scale_matrix))) * 3600.0)
        pad = margin / scale
        box = (int(np.ceil(np.ptp(py) + 2 * pad)) + 1, int(np.ceil(np.ptp(px) + 2 * pad)) + 1)
        centre = ((px.min() + px.max()) / 2, (py.min() + py.max()) / 2)
        cut = Cutout2D(data, centre, box, wcs=wcs, mode="partial", fill_value=np.nan)
        ax = fig.add_subplot(1, n_panels, k + 1, projection=cut.wcs)
        finite = np.isfinite(cut.data)
        norm = ImageNormalize(cut.data[finite] if finite.any() else None,
                              interval=PercentileInterval(99.5), stretch=AsinhStretch(0.05))
        ax.imshow(cut.data, origin="lower", cmap="gray_r", norm=norm)
        cx, cy = cut.wcs.world_to_pixel(sky)
        radius = 0.12 / scale
        good = np.isfinite(cx) & np.isfinite(cy)
        if good.sum() > 1:
            from scipy.spatial import cKDTree

            pts = np.column_stack([cx[good], cy[good]])
            nearest = cKDTree(pts).query(pts, k=2)[0]
            radius = min(radius, 0.4 * float(np.median(nearest[:, 1])))
        for x, y, pid, c in zip(cx, cy, ids, colour, strict=True):
            if not (np.isfinite(x) and np.isfinite(y)):
                continue  # a pair whose position on this arc was not measured
            ax.add_patch(plt.Circle((x, y), radius, fill=False, color=c, lw=1.2,
                                    path_effects=outline))
            ax.annotate(str(pid), (x, y), xytext=(4, 4), textcoords="offset points",
                        color=c, fontsize=8, fontweight="bold", path_effects=outline)
        ny, nx = cut.data.shape
        length = scale_bar / scale
        x0, y0 = 0.06 * nx, 0.06 * ny
        ax.plot([x0, x0 + length], [y0, y0], color="k", lw=2)
        ax.text(x0 + length / 2, y0 + 0.02 * ny, f'{scale_bar:g}"', ha="center", va="bottom")
        if not north:
            ax.text(0.97, 0.03, "not north-up", transform=ax.transAxes, ha="right",
                    fontsize=7, color="0.3")
        ax.coords[0].set_axislabel("RA")
        ax.coords[1].set_axislabel("Dec")
        ax.set_title(f"arc {arc}" + (f" ({band})" if band else ""))
    if mapped:
        ax = fig.add_subplot(1, n_panels, 3)
        plot_pairing_map(result, ax=ax)
        ax.set_title("mapped view (L1 rotated onto L2)")
    fig.tight_layout()
    return fig

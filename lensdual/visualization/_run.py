"""The figures that ``lensdual demo`` and ``lensdual run`` write to their output directory.

Each function returns a finished figure (titled, laid out) on a file backend;
``lensdual._outputs`` saves and closes it.
"""

from ._common import _headless_plt
from ._duality import plot_duality, plot_pairing_map
from ._images import plot_arc_images
from ._parametric import plot_size_vs_model

__all__ = []


def pairing_map_figure(analysis, title):
    """``pairing_map.png``: the pairing of an `~lensdual.pipeline.Analysis`."""
    plt = _headless_plt()
    fig, ax = plt.subplots(figsize=(5.5, 5.5))
    plot_pairing_map(analysis.pairs, analysis.catalogs["L1"], analysis.catalogs["L2"], ax=ax)
    ax.set_title(f"{title}: pairing (L1 rotated onto L2)", fontsize="medium")
    fig.tight_layout()
    return fig


def constellation_figure(analysis, images, title):
    """``constellation.png``: the pairs on both arcs' images."""
    _headless_plt()
    # two panels: the mapped view is pairing_map.png
    fig = plot_arc_images(images, analysis.result, mapped=False)
    fig.suptitle(f"{title}: the pairs on both arcs", fontsize="medium")
    fig.tight_layout(rect=(0, 0, 1, 0.94))  # room for the title above the panels
    return fig


def duality_figure(analysis, title):
    """``duality.png``: flux against size magnification."""
    plt = _headless_plt()
    fig, ax = plt.subplots(figsize=(5.5, 5.5))
    plot_duality(analysis.result, ax=ax, title=f"{title}: duality test")
    fig.tight_layout()
    return fig


def knot_figure(table):
    """``mu_size`` against the models' ratios of one knot table."""
    plt = _headless_plt()
    fig, ax = plt.subplots(figsize=(5.5, 5.5))
    plot_size_vs_model(table, ax=ax)
    fig.tight_layout()
    return fig

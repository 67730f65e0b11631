"""Make the sensitivity figures of docs/sensitivity.rst and print its comparison table.

Writes docs/_static/sensitivity_fig7.png (source-plane flux excess of the
paper's over-concentrated sub-halo on the SMACS0723 analogue's L2 image,
with the unit ellipses) and docs/_static/sensitivity_fig9.png (detection SNR
over mass and r_eff, 50/68/95th percentiles over 36 angles, mass-concentration
relation and 5 times over-concentrated), then writes into
docs/_static/sensitivity/ the statistics that docs/sensitivity.rst compares
with the paper's text, for the reproduction settings and for one change at a
time: ``settings.txt`` (the table), ``numbers.inc`` (reST substitutions of the
numbers the page quotes from the maps) and ``reference.inc`` (the reference
errors of :func:`~lensdual.sensitivity.smacs0723_reference`, which
tests/test_docs_numbers.py recomputes). Takes about two minutes on one core;
run from the repository root::

    python docs/scripts/sensitivity_maps.py
"""

from pathlib import Path

import astropy.units as u
import matplotlib
import numpy as np

matplotlib.use("agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import Ellipse  # noqa: E402

from lensdual.abundance import (  # noqa: E402
    detection_probability_limit,
    einstein_radius,
    surface_density_limit,
)
from lensdual.sensitivity import (  # noqa: E402
    detection_snr_map,
    effective_radius,
    effective_radius_ellipse,
    flux_excess,
    plot_detection_snr_map,
    smacs0723_reference,
)
from lensdual.simulation.halos import tnfw_halo  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
STATIC = ROOT / "docs" / "_static"
INCLUDES = STATIC / "sensitivity"

MASSES = np.geomspace(1e7, 1e10, 20) * u.Msun
R_EFF = np.arange(1, 25) * 0.125
# the reproduction: L2 of the analogue, the paper's r_eff, mu_flux/mu_size - 1,
# and the paper's ~10 % error of mu_size
BASE = {"sigma_rel": 0.10, "signal": "ratio", "definition": "paper"}


def fig7(a_l2):
    """Source-plane map of the flux excess, Table 1's over-concentrated sub-halo."""
    m = 1e8 * u.Msun
    te = einstein_radius(m, 0.39, 2.2)
    sub = tnfw_halo(m, 100.0, z_lens=0.39, z_source=2.2)
    half, n = 1.7, 341
    g = np.linspace(-half, half, n)
    bx, by = np.meshgrid(g, g)
    b = np.column_stack([bx.ravel(), by.ravel()]) * te.value  # source minus sub-halo
    d = -np.linalg.solve(a_l2, b.T).T  # image-plane offsets of the sub-halo
    fe, cnt = flux_excess(a_l2, sub, d * u.arcsec, return_counts=True)
    fig, ax = plt.subplots(figsize=(5.6, 4.6))
    im = ax.pcolormesh(g, g, np.log10(fe).reshape(n, n), cmap="RdBu_r", vmin=-0.5, vmax=0.5,
                       shading="nearest")
    ax.contour(g, g, (cnt >= 3).reshape(n, n).astype(float), levels=[0.5], colors="k",
               linewidths=0.6)
    for definition, style in (("paper", "--"), ("caustic", ":")):
        axes, angle = effective_radius_ellipse(a_l2, te, definition=definition)
        ax.add_patch(Ellipse((0, 0), 2 * axes[0] / te, 2 * axes[1] / te, angle=angle.value,
                             fill=False, ls=style, color="k", lw=1.2,
                             label=f'$r_{{\\rm eff}} = 1$, definition="{definition}"'))
    ax.set_aspect("equal")
    ax.set_xlabel(r"source $-$ sub-halo, x [$\theta_E$]")
    ax.set_ylabel(r"y [$\theta_E$]")
    ax.legend(loc="upper right", fontsize=7)
    fig.colorbar(im, ax=ax, label=r"$\log_{10}$ flux excess")
    ax.set_title(r"$10^8 M_\odot$, c = 100, on L2 (saddle); solid: 3+ images", fontsize=9)
    fig.tight_layout()
    fig.savefig(STATIC / "sensitivity_fig7.png", dpi=110)
    plt.close(fig)
    inside = cnt >= 3
    r_in = effective_radius(d[inside] * u.arcsec, a_l2, te)
    r_in_c = effective_radius(d[inside] * u.arcsec, a_l2, te, definition="caustic")
    print(f"Fig. 7: 3+ images up to r_eff = {r_in.max():.2f} (paper), "
          f"{r_in_c.max():.2f} (caustic definition)")
    return {"fig7_reach": f"{r_in.max():.2f}", "fig7_reach_caustic": f"{r_in_c.max():.2f}"}


def snr_maps(**kw):
    return [detection_snr_map(MASSES, R_EFF, concentration=c, **kw) for c in ("mcr", 5.0)]


def fig9(maps):
    fig, axes = plt.subplots(2, 3, figsize=(11, 6.4), sharex=True, sharey=True,
                             layout="constrained")
    for row, t, name in zip(axes, maps, ("mass-concentration relation", "5 x concentration"),
                            strict=True):
        _, mesh = plot_detection_snr_map(t, axes=row)
        row[0].set_ylabel(f"{name}\n" + r"$M_{200}$ [$M_\odot$]")
    for ax in axes[0]:
        ax.set_xlabel("")
    fig.colorbar(mesh, ax=axes, label="SNR", shrink=0.8)
    fig.savefig(STATIC / "sensitivity_fig9.png", dpi=100)
    plt.close(fig)


def _grid(t, col):
    return np.asarray(t[col], dtype=float).reshape(MASSES.size, R_EFF.size)


def _reach(z, level):
    """Median over masses of the largest r_eff with z > level (0 if none)."""
    out = [R_EFF[row > level].max() if (row > level).any() else 0.0 for row in z]
    return float(np.median(out))


def parts(maps, scale=1.0):
    """The statistics of one setting, ``{name: text}``."""
    mcr, over = maps
    mean = _grid(over, "snr_mean") * scale
    p50 = _grid(over, "snr_p50") * scale
    p95 = _grid(over, "snr_p95") * scale
    inside = R_EFF < 1
    ring = (R_EFF >= 0.75) & (R_EFF <= 1.25)
    ring_max = p95[:, ring].max(axis=1)
    mp50 = _grid(mcr, "snr_p50") * scale
    mp95 = _grid(mcr, "snr_p95") * scale
    return {"mean": f"{np.median(mean[:, inside]):.1f}",
            "cells10": f"{100 * (mean[:, inside] > 10).mean():.0f} %",
            "ring": f"{np.median(ring_max):.0f}",
            "ring_range": f"{ring_max.min():.0f}-{ring_max.max():.0f}",
            "reach95": f"{_reach(p95, 5):.2f}", "reach50": f"{_reach(p50, 5):.2f}",
            "mcr_p50": f"{mp50.max():.1f}", "mcr_cells": f"{100 * (mp95 > 5).mean():.0f} %",
            "mcr_reach": f"{_reach(mp95, 5):.2f}"}


def stats(p):
    """The table's cells of one setting from :func:`parts`."""
    return [f"{p['mean']} ({p['cells10']})", f"{p['ring']} ({p['ring_range']})",
            f"{p['reach95']} / {p['reach50']}", p["mcr_p50"],
            f"{p['mcr_cells']} / {p['mcr_reach']}"]


def reference_errors():
    """``sigma_rel`` of :func:`smacs0723_reference` (calibrated and Quad) per ``sigma_pos``."""
    out = {}
    for sp in (0.06, 0.005, 0.002):
        for method in ("adaptive", "quad"):
            ref = smacs0723_reference(sigma_pos=sp * u.arcsec, method=method)
            out[(sp, method)] = ref["sigma_rel"]
    return out


def _mas(sp):
    return f"{sp * 1000:g}"


def reference_numbers(errors):
    """``{name: text}`` of the reference errors (two or three significant digits)."""
    return {f"{'cal' if m == 'adaptive' else 'quad'}_{_mas(sp)}mas":
            f"{v:.2f}" if v >= 0.5 else f"{v:.3f}" for (sp, m), v in errors.items()}


def joint_reference_error(sigma_pos_mas):
    """The joint test's ``sigma_rel`` at ``sigma_pos_mas`` from the stored
    ``docs/_static/joint/reference_sigma.txt``."""
    lines = (STATIC / "joint" / "reference_sigma.txt").read_text().split("\n")
    head = lines[0].split()
    for line in lines[1:]:
        words = line.split()
        if words and float(words[0]) == sigma_pos_mas:
            return float(words[head.index("sigma_rel_joint")])
    raise ValueError(f"no joint reference error at {sigma_pos_mas} mas")


def binomial_bounds(reaches, mass=1e8 * u.Msun):
    """The paper's binomial bound on the sub-halo surface density (12 sources
    on each of two arcs, none flagged, 95 %) for ``mass``, with ``zeta`` the
    reach of each setting on the over-concentrated map (the median over masses
    of the largest ``r_eff`` whose median or 95th-percentile SNR over the
    angles exceeds 5); "none" where nothing is detectable."""
    p_det = detection_probability_limit(12, n_arcs=2, confidence=0.95)
    out = {}
    for name, reach in reaches.items():
        zeta = float(reach)
        if zeta > 0:
            bound = surface_density_limit(p_det, mass, z_lens=0.39, z_source=2.2, zeta=zeta)
            out[f"bound_{name}"] = f"{bound.to_value(u.kpc**-2):.2f} kpc\\ :sup:`-2`"
        else:
            out[f"bound_{name}"] = "none"
    return out


def substitutions(values):
    """reST substitution definitions, ``|sens_<name>|``, one a line."""
    return "".join(f".. |sens_{k}| replace:: {v}\n" for k, v in values.items())


def main():
    ref = smacs0723_reference()
    a_l2 = ref["jacobian"]
    numbers = fig7(a_l2)
    base = snr_maps(jacobian=a_l2, **BASE)
    fig9(base)
    numbers.update({f"base_{k}": v for k, v in parts(base).items()})
    rows = [("paper (text of Sect. 5.2.3)", ["often > 10", "~50", "~2 (percentile?)",
                                             "modest", "'a handful of locations'"]),
            ("reproduction (L2 saddle, paper r_eff, |f - 1|, 0.10)", stats(parts(base)))]
    lam, vec = np.linalg.eigh(a_l2)
    a_min = vec @ np.diag(np.abs(lam)) @ vec.T
    a_l1 = smacs0723_reference(image=1)["jacobian"]
    variants = [
        ('r_eff definition="caustic"', dict(BASE, definition="caustic"), a_l2, 1.0),
        ('signal "log": |ln f|', dict(BASE, signal="log"), a_l2, 1.0),
        ('signal "inverse": |1/f - 1|', dict(BASE, signal="inverse"), a_l2, 1.0),
        ("random angle phases (seed=1)", dict(BASE, seed=1), a_l2, 1.0),
        ("perturbed image L1 (maximum)", BASE, a_l1, 1.0),
        ("a minimum, |lambda_i| of L2", BASE, a_min, 1.0),
    ]
    for name, kw, a, scale in variants:
        rows.append((name, stats(parts(snr_maps(jacobian=a, **kw), scale))))
    p = parts(base, 0.10 / 0.05)
    numbers.update({f"s005_{k}": v for k, v in p.items()})
    rows.append(("sigma_rel = 0.05 (App. B's 5 %)", stats(p)))
    quad = smacs0723_reference(method="quad")
    rows.append((f"sigma_rel = {quad['sigma_rel']:.2f} (Quad bootstrap, 0.06 arcsec)",
                 stats(parts(base, 0.10 / quad["sigma_rel"]))))
    # the default of detection_snr_map: the calibrated (adaptive) error
    p = parts(base, 0.10 / ref["sigma_rel"])
    numbers.update({f"cal60_{k}": v for k, v in p.items()})
    rows.append((f"sigma_rel = {ref['sigma_rel']:.2f} (calibrated, 0.06 arcsec; default)",
                 stats(p)))
    for sp in (0.005, 0.002):
        cal = smacs0723_reference(sigma_pos=sp * u.arcsec)
        qd = smacs0723_reference(sigma_pos=sp * u.arcsec, method="quad")
        p = parts(base, 0.10 / cal["sigma_rel"])
        numbers.update({f"cal{_mas(sp)}_{k}": v for k, v in p.items()})
        rows.append((f"sigma_rel = {cal['sigma_rel']:.3f} (calibrated, {sp:g} arcsec; "
                     f"Quad {qd['sigma_rel']:.3f})", stats(p)))
    # the joint test's reference error at 0.06 arcsec (docs/scripts/joint_reference_errors.py)
    joint = joint_reference_error(60)
    p = parts(base, 0.10 / joint)
    numbers.update({f"joint60_{k}": v for k, v in p.items()})
    rows.append((f"sigma_rel = {joint:.3f} (joint test, 0.06 arcsec)", stats(p)))
    numbers.update(binomial_bounds({f"{name}_{q}": numbers[f"{name}_reach{q}"]
                                    for name in ("cal60", "joint60") for q in ("50", "95")}))
    head = ["setting", "mean SNR, r_eff < 1 (cells > 10)", "max p95, r_eff 0.75-1.25",
            "reach p95 / p50 > 5", "MCR: max p50",
            "MCR: cells p95 > 5 / reach"]
    table = [head] + [[name] + vals for name, vals in rows]
    widths = [max(len(r[i]) for r in table) for i in range(len(head))]
    line = "  ".join("=" * w for w in widths)
    lines = [line]
    for i, r in enumerate(table):
        lines.append("  ".join(v.ljust(w) for v, w in zip(r, widths, strict=True)).rstrip())
        if i == 0:
            lines.append(line)
    lines.append(line)
    text = "\n".join(lines) + "\n"
    print(text, end="")
    INCLUDES.mkdir(parents=True, exist_ok=True)
    (INCLUDES / "settings.txt").write_text(text)
    (INCLUDES / "numbers.inc").write_text(substitutions(numbers))
    (INCLUDES / "reference.inc").write_text(substitutions(reference_numbers(reference_errors())))
    print(f"wrote {INCLUDES}")


if __name__ == "__main__":
    main()

"""Sub-halo sensitivity: flux excess of a macro image perturbed by a sub-halo (paper Sect. 5.2.3).

Local model: a point source whose macro image sits at ``theta0`` where the
macro lens is locally linear, ``beta - beta0 = A0 (theta - theta0)`` with
``A0 = d beta / d theta`` (valid because a sub-halo's Einstein radius,
0.005-0.05 arcsec, is tiny compared with the scale on which the macro field
varies). A circular sub-halo at image-plane offset ``d`` from the macro
image adds ``alpha_sub(theta - theta0 - d)``; the images of the source solve

    0 = A0 (theta - theta0) - alpha_sub(theta - theta0 - d).

Definitions
-----------
``r_eff`` (``definition="paper"``, the default)
    The paper's Fig. 7 and 9: the sub-halo's isolated (point-mass)
    Einstein ring of radius ``theta_E``, mapped to the source plane by the
    macro deformation tensor ``A0``, is the *unit ellipse*; a source at
    source-plane offset ``b`` from the sub-halo (mapped by the macro
    model) has ``r_eff = |A0^-1 b| / theta_E``. Since ``b = -A0 d``, this is
    the image-plane separation of sub-halo and macro image in Einstein
    radii, ``r_eff = |d| / theta_E`` (Fig. 9's "distance in the image plane
    normalised to the Einstein radius"; also the paper's ``zeta theta_E``
    of Sect. 5.4).
``r_eff`` (``definition="caustic"``)
    An alternative scaled to the point-mass caustic: with ``lambda_i, e_i``
    the eigenvalues and eigenvectors of (the symmetric part of) ``A0``,
    ``r_eff = sqrt(sum_i |lambda_i| (d . e_i)^2) / (2 theta_E)``; the unit
    ellipse has image-plane semi-axes ``2 theta_E / sqrt(|lambda_i|)``
    (twice the Einstein radius enlarged by the macro field, where a point
    mass's shear ``theta_E^2 / r^2`` equals ``|lambda_i|``). At a saddle
    the point-mass caustic has its cusps on the axis of the negative
    eigenvalue exactly at ``r_eff = 1`` (at ``r_eff = 2 / sqrt(|lambda_-|)``
    in the paper's units).
Flux excess
    ``f = sum_i |mu_i| / |mu_0|`` over all micro-images, ``mu_0 = 1 / det A0``;
    1 without sub-halo.
Detection SNR
    ``|mu_flux / mu_size - 1| / sigma_rel`` with ``mu_flux / mu_size = f``
    (the sub-halo on the image in the numerator of the flux ratio) and
    ``sigma_rel`` the relative error of ``mu_size``; alternatives
    ``|ln f|`` and ``|1 / f - 1|`` (see :func:`detection_snr_map`).
"""

from ..visualization._sensitivity import plot_detection_snr_map, plot_flux_excess_violin
from ._images import flux_excess, flux_excess_distribution, micro_images, subhalo_einstein_radius
from ._radius import effective_radius, effective_radius_ellipse, offsets_on_ellipse
from ._reference import smacs0723_reference
from ._snr import detection_snr_map

# Modules: _inputs (checks), _radius (r_eff), _images (micro-images, flux
# excess), _reference (the SMACS0723 analogue), _snr (detection-SNR maps and
# their tasks), _kernels (Numba); the figures (Figs. 8 and 9) are
# lensdual.visualization's, re-exported here.
__all__ = [
    "effective_radius_ellipse",
    "effective_radius",
    "offsets_on_ellipse",
    "subhalo_einstein_radius",
    "micro_images",
    "flux_excess",
    "flux_excess_distribution",
    "plot_flux_excess_violin",
    "smacs0723_reference",
    "detection_snr_map",
    "plot_detection_snr_map",
]

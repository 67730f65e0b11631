"""The recursive multi-plane lens equation of a Lenstool model with several ``z_lens``.

With the planes at ``z_1 < z_2 < ... < z_P`` in front of a source at ``z_s``
(index ``P + 1``), and :math:`\\hat\\alpha_i` the deflection of the potentials
of plane ``i`` for ``D_ls / D_s = 1`` (Lenstool's ``b0``, from ``v_disp``, in
the angular frame of that plane), a ray seen at :math:`\\theta` crosses plane
``j`` at

.. math::

    \\theta_1 = \\theta, \\qquad
    \\theta_j = \\theta - \\sum_{i<j} \\frac{D_{ij}}{D_j}
        \\hat\\alpha_i(\\theta_i), \\qquad
    \\beta = \\theta_{P+1},

(Blandford & Narayan 1986; Schneider, Ehlers & Falco 1992, ch. 9) with
angular diameter distances :math:`D_{ij}` between planes and :math:`D_j` from
the observer. Its Jacobian follows the same recursion,

.. math::

    A_1 = I, \\qquad A_j = I - \\sum_{i<j} \\frac{D_{ij}}{D_j} H_i A_i,

with :math:`H_i` the Hessian of plane ``i``'s potentials at
:math:`\\theta_i`. A single plane reduces to ``beta = theta - D_ls / D_s
alpha``. Each plane is evaluated by the Numba kernels of its own
`~lensdual.parametric.LenstoolLensModel`; the loop over planes is plain
Python on arrays.
"""

import numpy as np
from astropy import units as u

from .._lens.model import LensModelBase, plain_positions
from .._validation import as_int

__all__ = []


def plane_distance_ratios(cosmology, z_planes, z_source):
    """``D_ij / D_j`` for the planes ``z_planes`` (increasing) and the source.

    Returns an array ``r`` of shape (P + 1, P + 1): ``r[i, j] = D(z_i, z_j) /
    D(0, z_j)`` for ``i < j``, the source being index P; 0 elsewhere.
    """
    z = [float(v) for v in z_planes] + [float(z_source)]
    n = len(z)
    r = np.zeros((n, n))
    for j in range(1, n):
        d_j = cosmology.angular_diameter_distance(z[j])
        for i in range(j):
            d_ij = cosmology.angular_diameter_distance(z[i], z[j])
            r[i, j] = float((d_ij / d_j).to_value(u.dimensionless_unscaled))
    return r


class LenstoolMultiPlaneLensModel(LensModelBase):
    """Potentials on several lens planes, with lenstronomy's ``LensModel`` interface.

    Made by `LenstoolModel.lens_model` for a source behind two or more of a
    model's planes. Positions are plain float arrays (any shape, broadcast
    together) in arcsec in the model frame, as for `LenstoolLensModel`;
    every method takes lenstronomy's ``kwargs`` argument and ignores it.
    ``alpha`` is ``theta - beta``; ``hessian`` returns ``(f_xx, f_xy, f_yx,
    f_yy) = I - A`` of the full multi-plane Jacobian ``A = d beta / d theta``
    (``f_xy = d alpha_x / d y`` and ``f_yx = d alpha_y / d x`` differ in
    general, as in lenstronomy's ``MultiPlane``); ``kappa`` is ``(f_xx + f_yy)
    / 2`` and ``magnification`` ``1 / det A`` of that Jacobian.

    Parameters
    ----------
    planes : sequence of `LenstoolLensModel`
        One per plane, increasing redshift, normalised for ``D_ls / D_s = 1``
        (unscaled ``b0``, ``gamma`` and ``kappa``).
    z_planes : sequence of float
        Their redshifts, increasing, all below ``z_source``.
    ratios : numpy.ndarray, shape (P + 1, P + 1)
        ``D_ij / D_j`` (see :func:`plane_distance_ratios`).
    z_source : float
        Source redshift (kept for reference).
    """

    def __init__(self, planes, z_planes, ratios, *, z_source):
        self.planes = tuple(planes)
        self.z_planes = tuple(float(z) for z in z_planes)
        n = len(self.planes)
        if n < 1 or len(self.z_planes) != n:
            raise ValueError("give one model per plane and as many redshifts")
        if any(b <= a for a, b in zip(self.z_planes, self.z_planes[1:], strict=False)):
            raise ValueError(f"z_planes must increase, got {self.z_planes}")
        if not self.z_planes[-1] < z_source:
            raise ValueError(f"every plane must be in front of the source (z_source="
                             f"{z_source}), got z_planes={self.z_planes}")
        ratios = np.array(ratios, dtype=float)
        if ratios.shape != (n + 1, n + 1):
            raise ValueError(f"ratios must have shape {(n + 1, n + 1)}, got {ratios.shape}")
        ratios.flags.writeable = False
        self.ratios = ratios
        self.z_source = float(z_source)

    @property
    def n_threads(self):
        return self.planes[0].n_threads

    @n_threads.setter
    def n_threads(self, value):
        value = as_int(value, "n_threads", minimum=1)
        for plane in self.planes:
            plane.n_threads = value

    @property
    def centres(self):
        """Centres ``(x, y)`` of the mass components of all planes, in plane order."""
        return np.concatenate([p.centres for p in self.planes])

    def __repr__(self):
        parts = ", ".join(f"z={z}: {len(p.params)} dPIE + {len(p.nfw_params)} NFW"
                          + (f" + {len(p.shear_params)} shear" if len(p.shear_params) else "")
                          for z, p in zip(self.z_planes, self.planes, strict=True))
        return f"<LenstoolMultiPlaneLensModel {parts}; z_source={self.z_source}>"

    def _trace(self, x, y, jacobian):
        """Ray positions in the source plane and, if asked, ``A = d beta / d theta``."""
        x, y = plain_positions(x, y)
        r = self.ratios
        n = len(self.planes)
        alphas = []
        hjac = []  # H_i A_i per plane: (b11, b12, b21, b22)
        for j in range(n + 1):
            xj, yj = x, y
            a11 = a22 = 1.0
            a12 = a21 = 0.0
            for i in range(j):
                xj = xj - r[i, j] * alphas[i][0]
                yj = yj - r[i, j] * alphas[i][1]
                if jacobian:
                    b11, b12, b21, b22 = hjac[i]
                    a11 = a11 - r[i, j] * b11
                    a12 = a12 - r[i, j] * b12
                    a21 = a21 - r[i, j] * b21
                    a22 = a22 - r[i, j] * b22
            if j == n:
                return xj, yj, (a11, a12, a21, a22)
            if jacobian:
                ax, ay, fxx, fxy, fyy = self.planes[j].alpha_hessian(xj, yj)
                hjac.append((fxx * a11 + fxy * a21, fxx * a12 + fxy * a22,
                             fxy * a11 + fyy * a21, fxy * a12 + fyy * a22))
            else:
                ax, ay = self.planes[j].alpha(xj, yj)
            alphas.append((ax, ay))

    # the LensModel methods below show LensModelBase's docstrings
    def ray_shooting(self, x, y, kwargs=None, k=None):
        bx, by, _ = self._trace(x, y, False)
        return bx, by

    def alpha(self, x, y, kwargs=None, k=None):
        bx, by, _ = self._trace(x, y, False)
        return np.subtract(x, bx), np.subtract(y, by)

    def hessian(self, x, y, kwargs=None, k=None, diff=None):
        _, _, (a11, a12, a21, a22) = self._trace(x, y, True)
        return 1.0 - a11, -a12, -a21, 1.0 - a22

    def alpha_hessian(self, x, y, kwargs=None):
        bx, by, (a11, a12, a21, a22) = self._trace(x, y, True)
        return (np.subtract(x, bx), np.subtract(y, by), 1.0 - a11, -0.5 * (a12 + a21),
                1.0 - a22)

    def _jacobian(self, x, y):
        """``A = d beta / d theta`` of the multi-plane recursion (not ``I - H``)."""
        return self._trace(x, y, True)[2]

"""Derived lensing quantities of a model with lenstronomy's ``LensModel`` interface."""

import numpy as np

__all__ = ["LensModelBase"]


class LensModelBase:
    """Convergence, shear, magnification and ray shooting from a model's deflection and Hessian.

    A subclass supplies ``alpha(x, y, kwargs=None, k=None)``, the deflection,
    and ``hessian(x, y, kwargs=None, k=None, diff=None)``, the second
    derivatives ``(f_xx, f_xy, f_yx, f_yy)`` of the lensing potential, on
    plain float arrays in arcsec; the methods here take lenstronomy's
    ``kwargs`` and ``k`` arguments and pass nothing on. A subclass with a
    closed-form convergence overrides ``_kappa(x, y)``, one that computes
    the Jacobian ``d beta / d theta`` directly (a multi-plane model)
    overrides ``_jacobian(x, y)``, and one that traces rays directly
    overrides `ray_shooting`.
    """

    def ray_shooting(self, x, y, kwargs=None, k=None):
        """Source-plane positions ``beta = theta - alpha(theta)``, arcsec.

        Parameters
        ----------
        x, y : array_like
            Image-plane positions, arcsec (any shape).
        kwargs, k
            Ignored (lenstronomy's ``LensModel`` interface).

        Returns
        -------
        beta_x, beta_y : `~numpy.ndarray`
            Source-plane positions, arcsec, of the shape of ``x``.
        """
        ax, ay = self.alpha(x, y)
        return np.subtract(x, ax), np.subtract(y, ay)

    def kappa(self, x, y, kwargs=None, k=None):
        """Convergence ``(f_xx + f_yy) / 2`` (the closed form where the model has one).

        Parameters
        ----------
        x, y : array_like
            Image-plane positions, arcsec (any shape).
        kwargs, k
            Ignored (lenstronomy's ``LensModel`` interface).

        Returns
        -------
        kappa : `~numpy.ndarray`
            Of the shape of ``x``.
        """
        return self._kappa(x, y)

    def gamma(self, x, y, kwargs=None, k=None):
        """Shear ``gamma_1 = (f_xx - f_yy) / 2`` and ``gamma_2 = f_xy``, as lenstronomy's.

        Parameters
        ----------
        x, y : array_like
            Image-plane positions, arcsec (any shape).
        kwargs, k
            Ignored (lenstronomy's ``LensModel`` interface).

        Returns
        -------
        gamma_1, gamma_2 : `~numpy.ndarray`
            Of the shape of ``x``.
        """
        fxx, fxy, _, fyy = self.hessian(x, y)
        return 0.5 * (fxx - fyy), fxy

    def magnification(self, x, y, kwargs=None, k=None):
        """Signed magnification ``1 / det(d beta / d theta)``.

        Parameters
        ----------
        x, y : array_like
            Image-plane positions, arcsec (any shape).
        kwargs, k
            Ignored (lenstronomy's ``LensModel`` interface).

        Returns
        -------
        mu : `~numpy.ndarray`
            Of the shape of ``x``; infinite where the determinant is zero.
        """
        a11, a12, a21, a22 = self._jacobian(x, y)
        with np.errstate(divide="ignore"):
            return 1.0 / (a11 * a22 - a12 * a21)

    def _kappa(self, x, y):
        fxx, _, _, fyy = self.hessian(x, y)
        return 0.5 * (fxx + fyy)

    def _jacobian(self, x, y):
        """``d beta / d theta = I - H`` as ``(a_11, a_12, a_21, a_22)``."""
        fxx, fxy, fyx, fyy = self.hessian(x, y)
        return 1.0 - fxx, -fxy, -fyx, 1.0 - fyy

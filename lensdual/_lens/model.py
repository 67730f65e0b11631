"""Derived lensing quantities of a model with lenstronomy's ``LensModel`` interface."""

import numpy as np
from astropy import units as u

__all__ = ["LensModelBase", "plain_positions"]

# The Parameters section every method of the interface shares; ``{ignored}`` names
# the lenstronomy arguments the method takes and ignores.
_PARAMETERS = """Parameters
        ----------
        x, y : array_like
            Image-plane positions, arcsec (any shape).
        {ignored}
            Ignored (lenstronomy's ``LensModel`` interface)."""


def _interface(returns, ignored="kwargs, k"):
    """Complete a method's docstring with the shared Parameters and its Returns section."""
    def complete(method):
        method.__doc__ = (method.__doc__.rstrip() + "\n\n        "
                          + _PARAMETERS.format(ignored=ignored)
                          + "\n\n        Returns\n        -------\n        " + returns + "\n")
        return method
    return complete


_OF_X = "\n            Of the shape of ``x``."


def plain_positions(x, y):
    """``x`` and ``y`` as float64 arrays of their common broadcast shape.

    The lens models take lenstronomy's interface: plain float arrays in
    arcsec; `~lensdual.simulation.LensSystem` is the one that takes Quantities.

    Parameters
    ----------
    x, y : array_like
        Image-plane positions, arcsec.

    Returns
    -------
    x, y : `~numpy.ndarray`
        float64 broadcast views of ``x`` and ``y``.

    Raises
    ------
    TypeError
        If ``x`` or ``y`` is a `~astropy.units.Quantity`.
    """
    if isinstance(x, u.Quantity) or isinstance(y, u.Quantity):
        raise TypeError("x and y are plain float arrays in arcsec (lenstronomy's "
                        "interface); use LensSystem for Quantities")
    return np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))


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
    overrides `ray_shooting`. The docstrings here are those of every model's
    methods (an override without a docstring shows the one here).
    """

    @_interface("alpha_x, alpha_y : `~numpy.ndarray`\n"
                "            The deflection, arcsec, of the shape of ``x``.")
    def alpha(self, x, y, kwargs=None, k=None):
        """Deflection ``(alpha_x, alpha_y)`` at ``(x, y)``, arcsec.

        For several lens planes, the effective deflection ``theta - beta(theta)``.
        """
        raise NotImplementedError(f"{type(self).__name__} supplies no deflection")

    @_interface("f_xx, f_xy, f_yx, f_yy : `~numpy.ndarray`" + _OF_X, ignored="kwargs, k, diff")
    def hessian(self, x, y, kwargs=None, k=None, diff=None):
        """``(f_xx, f_xy, f_yx, f_yy)``: the second derivatives of the potential.

        For several lens planes, ``I - d beta / d theta`` of the multi-plane
        Jacobian (``f_xy`` and ``f_yx`` then differ in general).
        """
        raise NotImplementedError(f"{type(self).__name__} supplies no Hessian")

    @_interface("alpha_x, alpha_y, f_xx, f_xy, f_yy : `~numpy.ndarray`" + _OF_X,
                ignored="kwargs")
    def alpha_hessian(self, x, y, kwargs=None):
        """Deflection and Hessian in one pass: ``alpha_x, alpha_y, f_xx, f_xy, f_yy``.

        ``f_xy`` is the mean of ``f_xy`` and ``f_yx`` where they differ (use
        `hessian` for both).
        """
        ax, ay = self.alpha(x, y)
        fxx, fxy, fyx, fyy = self.hessian(x, y)
        return ax, ay, fxx, 0.5 * (fxy + fyx), fyy

    @_interface("beta_x, beta_y : `~numpy.ndarray`\n"
                "            Source-plane positions, arcsec, of the shape of ``x``.")
    def ray_shooting(self, x, y, kwargs=None, k=None):
        """Source-plane positions ``beta = theta - alpha(theta)``, arcsec."""
        ax, ay = self.alpha(x, y)
        return np.subtract(x, ax), np.subtract(y, ay)

    @_interface("kappa : `~numpy.ndarray`" + _OF_X)
    def kappa(self, x, y, kwargs=None, k=None):
        """Convergence ``(f_xx + f_yy) / 2`` (the closed form where the model has one)."""
        return self._kappa(x, y)

    @_interface("gamma_1, gamma_2 : `~numpy.ndarray`" + _OF_X)
    def gamma(self, x, y, kwargs=None, k=None):
        """Shear ``gamma_1 = (f_xx - f_yy) / 2`` and ``gamma_2 = f_xy``, as lenstronomy's."""
        fxx, fxy, _, fyy = self.hessian(x, y)
        return 0.5 * (fxx - fyy), fxy

    @_interface("mu : `~numpy.ndarray`\n"
                "            Of the shape of ``x``; infinite where the determinant is zero.")
    def magnification(self, x, y, kwargs=None, k=None):
        """Signed magnification ``1 / det(d beta / d theta)``."""
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

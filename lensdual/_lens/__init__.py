"""The lens layer that `lensdual.parametric` and `lensdual.simulation` both build on.

`LensModelBase` gives a lens model with lenstronomy's ``LensModel``
interface its derived quantities (convergence, shear, magnification) from the
deflection and the Hessian the model supplies.
"""

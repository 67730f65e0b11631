"""The lens layer that `lensdual.parametric` and `lensdual.simulation` both build on.

``system``: `~lensdual.simulation.LensSystem` (lenstronomy profiles, or any
model with lenstronomy's ``LensModel`` interface, with redshifts and a
cosmology) and ``component``: `~lensdual.simulation.LensComponent`, both
re-exported by `lensdual.simulation`; ``_solver`` and ``_kernels``: the
point-source image finder of
`~lensdual.simulation.LensSystem.solve_images`; ``model``:
``LensModelBase``, which gives a lens model its convergence, shear,
magnification and ray shooting from the deflection and the Hessian it
supplies. Nothing here imports `lensdual.simulation` or `lensdual.parametric`.
"""

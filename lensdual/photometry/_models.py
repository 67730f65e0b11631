"""The astropy models fitted: one PSF plus a linear background, or a group of PSFs.

The classes are made on demand, one per set of background terms (and group
size), and cached: astropy models declare their parameters as class
attributes.
"""

import numpy as np
from astropy.modeling import Fittable2DModel, Parameter


class _PSFBackgroundModel(Fittable2DModel):
    """Base of the fitted models (PSF + linear background); see :func:`_model_class`."""

    _with_shape = False

    def __init__(self, profile=None, basis=None, **kwargs):
        super().__init__(**kwargs)
        self._profile = profile
        self._basis = basis

    def _split(self, params):
        if self._with_shape:
            return params[0], params[1:]
        return None, params

    def evaluate(self, x, y, flux, x_0, y_0, *params):
        shape, coeffs = self._split(params)
        out = flux * self._profile(x - x_0, y - y_0, shape)
        if coeffs:
            for c, col in zip(coeffs, self._basis.columns(x, y), strict=True):
                out = out + c * col
        return out

    def fit_deriv(self, x, y, flux, x_0, y_0, *params):
        shape, _ = self._split(params)
        dx, dy = x - x_0, y - y_0
        p = self._profile(dx, dy, shape)
        gx, gy = self._profile.grad(dx, dy, shape)
        out = [p, -flux * gx, -flux * gy]
        if self._with_shape:
            h = 1e-4 * shape
            out.append(
                flux
                * (self._profile(dx, dy, shape + h) - self._profile(dx, dy, shape - h))
                / (2 * h)
            )
        return out + self._basis.columns(x, y)

    def copy(self):
        """Copy the parameters only; the profile and basis are shared."""
        import copy

        new = object.__new__(self.__class__)
        for key, val in self.__dict__.items():
            new.__dict__[key] = copy.copy(val) if key in self.param_names else val
        return new


_MODEL_CLASSES = {}


def _model_class(names, with_shape):
    key = (tuple(names), with_shape)
    if key not in _MODEL_CLASSES:
        attrs = {
            "flux": Parameter(default=1.0),
            "x_0": Parameter(default=0.0),
            "y_0": Parameter(default=0.0),
        }
        if with_shape:
            attrs["fwhm"] = Parameter(default=2.0, bounds=(0.3, 50.0))
        for name in names:
            attrs[name] = Parameter(default=0.0)
        attrs["_with_shape"] = with_shape
        attrs["__module__"] = __name__
        attrs["__doc__"] = "PSF plus a linear background (lensdual internal)."
        cname = f"_PSF{len(names)}{'Shape' if with_shape else ''}"
        _MODEL_CLASSES[key] = type(cname, (_PSFBackgroundModel,), attrs)
    return _MODEL_CLASSES[key]


class _GroupModel(Fittable2DModel):
    """Several PSFs and one background (lensdual internal); see :func:`_group_class`."""

    _n = 0

    def __init__(self, profile=None, basis=None, centre=None, **kwargs):
        super().__init__(**kwargs)
        self._profile = profile
        self._basis = basis
        self._centre = centre

    def evaluate(self, x, y, *params):
        out = np.zeros(np.shape(x))
        for i in range(self._n):
            f, x0, y0 = params[3 * i : 3 * i + 3]
            out = out + f * self._profile(x - x0, y - y0)
        coeffs = params[3 * self._n :]
        if coeffs:
            cols = self._basis.columns(x, y, centre=self._centre)
            for c, col in zip(coeffs, cols, strict=True):
                out = out + c * col
        return out

    def fit_deriv(self, x, y, *params):
        out = []
        for i in range(self._n):
            f, x0, y0 = params[3 * i : 3 * i + 3]
            dx, dy = x - x0, y - y0
            gx, gy = self._profile.grad(dx, dy)
            out += [self._profile(dx, dy), -f * gx, -f * gy]
        return out + self._basis.columns(x, y, centre=self._centre)


_GROUP_CLASSES = {}


def _group_class(n, names):
    key = (n, tuple(names))
    if key not in _GROUP_CLASSES:
        attrs = {}
        for i in range(n):
            attrs[f"flux_{i}"] = Parameter(default=1.0)
            attrs[f"x_0_{i}"] = Parameter(default=0.0)
            attrs[f"y_0_{i}"] = Parameter(default=0.0)
        for name in names:
            attrs[name] = Parameter(default=0.0)
        attrs["_n"] = n
        attrs["__module__"] = __name__
        attrs["__doc__"] = "Several PSFs plus a linear background (lensdual internal)."
        _GROUP_CLASSES[key] = type(f"_Group{n}x{len(names)}", (_GroupModel,), attrs)
    return _GROUP_CLASSES[key]

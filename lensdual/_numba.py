"""The one place for the Numba options of lensdual's kernels.

Every ``_kernels.py`` module compiles with ``JIT_OPTIONS``: cached on disk,
never ``fastmath`` (it mishandles NaN, which the kernels use for "no
result"), and releasing the GIL so that thread pools can run kernels side by
side. ``parallel=True`` is used nowhere: on 2 cores the thread pools of the
callers pay, Numba's own parallelism did not (benchmarks/).

A kernel passes a constant integer argument to another kernel as a numpy
integer (a module constant such as ``np.int64(6)``), not as a Python int:
Numba compiles the callee once for every value of a Python-int constant (a
literal type) and once for all values of an int64. Where a callee's small
loops run faster compiled for a fixed size, a Python int is passed on purpose.
"""

#: Options of every ``numba.njit`` of the package.
JIT_OPTIONS = {"cache": True, "fastmath": False, "nogil": True}

#: The same, with NumPy's floating-point error model (division by zero gives inf
#: or NaN instead of raising), for kernels whose formulas divide by values that
#: may vanish and handle the result themselves.
JIT_OPTIONS_NUMPY_ERRORS = {**JIT_OPTIONS, "error_model": "numpy"}

"""Compiled kernels of the per-step hot path (numba ``njit``), cached on disk.

One small numpy call costs about a microsecond, so a filter step written as ~100
vectorised numpy calls spends most of its time in call overhead.  The hot path
therefore runs as a few compiled loops over the obstacles (``kernel``), each
with the math of its module's docstring.  Conventions:

* ``cache=True``: the machine code is stored beside the source (or in numba's
  per-user cache when that is read-only), so only the first process on a
  machine compiles; later ones load it in milliseconds.
* ``error_model='numpy'``: division by zero gives inf / NaN as in numpy instead
  of raising, so a kernel computes exactly what the numpy formulation would.
* Hot-path kernels write into arrays the caller allocated and return at most a
  few scalars: handing an array back from compiled code costs about a
  microsecond.
* Call them with C-contiguous float64 arrays, Python floats and bools: other
  types compile another version on first use (seconds, on the hot path).
"""
import numba

kernel = numba.njit(cache=True, nogil=True, error_model='numpy')

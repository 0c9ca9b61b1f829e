"""Compiled kernels of the per-step hot path: ahead of time, or numba ``njit``.

One small numpy call costs about a microsecond, so a filter step written as ~100
vectorised numpy calls spends most of its time in call overhead.  The hot path
therefore runs as a few compiled loops over the obstacles (``kernel``).  They all live
in this folder, one module per concept (``kernels.cones`` holds the kernels of
``barrier.cones``, whose docstring has the math), and import only each other and
this module; the concept modules import the kernels they call.

Two ways to run the same source:

* **Ahead of time** (the default once built): ``make`` runs
  ``python -m polyc2bf_ros.core.kernels.build``, which compiles every kernel
  that Python calls into one extension module, ``core/kernels/_kernels*.so``,
  beside a digest of this folder's sources (``kernel_sources``).  A
  process then loads the kernels without numba or LLVM and compiles nothing at
  start-up.  Each one sits behind its guard (``guard_source``,
  written out by the build), which checks dtype, rank and contiguity of every
  array argument (compiled code trusts its arguments: a float32 or strided
  array would be misread) and raises TypeError naming the kernel otherwise.
* **Just in time** (``numba.njit``, cached on disk): when the extension is
  missing, or the sources changed since it was built (the digest differs, so a
  stale build is never used), or ``POLYC2BF_KERNELS=jit``.  Numba compiles a
  kernel lazily for the types of its first call (helpers may be defined after
  their callers), so this mode is lenient where the guard is strict: the tests
  run ahead of time.

``POLYC2BF_KERNELS`` = ``auto`` (default) | ``aot`` (fail if not built) | ``jit``.

Why ahead of time, though numba deprecates ``pycc`` (``bench/bench_kernels.py``, medians of
five paired fresh processes, the default filter on 50 octagons): against ``njit(cache=True)``
with a warm cache, the first step comes after 0.58 s instead of 1.52 s, the process holds
44 MB instead of 170 MB, the step's p50 is within noise (173 / 220 us on a loaded machine),
and just in time the fourth step always pauses ~10 ms (cached kernels load lazily).  A
build that fails (no C compiler, a numba without ``pycc``) fails no install: ``make`` warns
and the kernels compile just in time.

Conventions for kernels:

* ``error_model='numpy'``: division by zero gives inf / NaN as in numpy instead
  of raising, so a kernel computes exactly what the numpy formulation would.
* Hot-path kernels write into arrays the caller allocated and return at most a
  few scalars: handing an array back from compiled code costs about a
  microsecond.
* ``@kernel(signature('void', F2, 'f8', ...))`` marks a kernel called from
  Python, with its numba signature (C-contiguous arrays ``F1``-``F3``;
  ``'f8[:, :]'`` where callers pass strided views); a bare ``@kernel`` marks a
  helper called only from other kernels, which numba inlines into them
  (``inline='always'``: a helper call otherwise costs reference counting of every
  array it is passed).  Numba's on-disk cache does not notice when a helper in
  another file changes; the ahead-of-time build never uses it, and in
  just-in-time mode deleting ``__pycache__/*.nbi`` clears it.
* ``kernel.unchecked`` is the compiled function without the guard, for the
  filter's per-step calls whose arrays the core itself allocated or converted
  (``np.empty``, ``np.ascontiguousarray(..., dtype=np.float64)``, prepared
  geometry): there the guard's ~15 attribute reads per call were ~8 % of a
  step on a cold cache.  Anything taking arrays from a caller stays guarded.
"""
import hashlib
import os
import re
import warnings
from pathlib import Path

import numpy as np

KERNELS = Path(__file__).resolve().parent
DIGEST_FILE = KERNELS / '_kernels.digest'
MODE_VARIABLE = 'POLYC2BF_KERNELS'
MODES = ('auto', 'aot', 'jit')
JIT_OPTIONS = {'cache': True, 'nogil': True, 'error_model': 'numpy'}

#: Argument types of exported kernels: C-contiguous float64 arrays of rank 1-3, int64 and
#: vectors and matrices, bool vectors (numba's notation; scalars are 'f8', 'i8', 'b1').
F1, F2, F3 = 'f8[::1]', 'f8[:, ::1]', 'f8[:, :, ::1]'
I1, I2, B1 = 'i8[::1]', 'i8[:, ::1]', 'b1[::1]'

#: Kernels called from Python, filled in just-in-time mode for the ahead-of-time build:
#: export name -> (numba dispatcher, signature string).
EXPORTS = {}

_DTYPES = {'f8': np.dtype(np.float64), 'i8': np.dtype(np.int64), 'b1': np.dtype(np.bool_)}
_ARRAY = re.compile(r'^(f8|i8|b1)\[([^\]]*)\]$')


def signature(result, *arguments):
    """Return the numba signature string ``result(arguments...)``."""
    return f'{result}({", ".join(arguments)})'


def kernel_sources():
    """Return the Python files of this folder, ``core/kernels`` (what the extension is built from).

    Every kernel lives here, one module per concept beside the machinery; the generated
    ``_guards.py`` does not count.  Editing any other file (the filter's Python around the
    kernels, the node) keeps the built kernels.
    """
    return sorted(path for path in KERNELS.glob('*.py') if path.name != '_guards.py')


def source_digest():
    """Return the SHA-256 over ``kernel_sources``, their paths and contents."""
    digest = hashlib.sha256()
    core = KERNELS.parent
    for path in kernel_sources():
        digest.update(path.relative_to(core).as_posix().encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def export_name(module, name):
    """Return the extension's symbol for kernel ``name`` of ``module``.

    ``polyc2bf_ros.core.kernels.views`` and ``_viewpoints``: ``core_kernels_views__viewpoints``.
    """
    return module.replace('polyc2bf_ros.', '').replace('.', '_') + '__' + name.lstrip('_')


def _load_ahead_of_time():
    """Return the built extension module, or None to compile just in time.

    The build writes ``_kernels*.so``, its guards ``_guards.py`` and the digest; a
    missing one counts as no build.
    """
    mode = os.environ.get(MODE_VARIABLE, 'auto')
    if mode not in MODES:
        raise ValueError(f'{MODE_VARIABLE} must be one of {", ".join(MODES)}, got {mode!r}')
    if mode == 'jit':
        return None
    try:
        from polyc2bf_ros.core.kernels import _guards, _kernels  # noqa: F401 (both built)
        built_from = DIGEST_FILE.read_text().strip()
    except (ImportError, OSError) as exc:
        if mode == 'aot':
            raise RuntimeError(f'{MODE_VARIABLE}=aot but the kernels are not built ({exc}); '
                               'run: python -m polyc2bf_ros.core.kernels.build') from exc
        return None
    if built_from != source_digest():
        message = ('the ahead-of-time kernels were built from other sources than these; '
                   'compiling just in time (rebuild: python -m polyc2bf_ros.core.kernels.build)')
        if mode == 'aot':
            raise RuntimeError(message)
        warnings.warn(message, RuntimeWarning, stacklevel=2)
        return None
    return _kernels


AHEAD_OF_TIME = _load_ahead_of_time()


def argument_checks(numba_signature):
    """Return per argument of a signature None (a scalar) or (dtype, ndim, contiguous)."""
    depth, start = 0, len(numba_signature) - 1
    while True:  # the argument list is the last parenthesised group
        depth += {')': 1, '(': -1}.get(numba_signature[start], 0)
        if depth == 0:
            break
        start -= 1
    arguments = numba_signature[start + 1:-1]
    checks = []
    for argument in re.split(r',\s*(?![^\[]*\])', arguments):
        match = _ARRAY.match(argument.strip())
        if match is None:
            checks.append(None)
            continue
        dims = [d.strip() for d in match.group(2).split(',')]
        checks.append((_DTYPES[match.group(1)], len(dims), dims[-1] == '::1'))
    return tuple(checks)


def check_arguments(name, checks, args):
    """Raise TypeError unless every array argument has the dtype, rank and layout of ``checks``."""
    for index, check in enumerate(checks):
        if check is None:
            continue
        dtype, ndim, contiguous = check
        array = args[index]
        if not (type(array) is np.ndarray and array.dtype == dtype and array.ndim == ndim
                and (array.flags.c_contiguous or not contiguous)):
            raise TypeError(f'kernel {name}: argument {index} must be a '
                            f'{"C-contiguous " if contiguous else ""}{dtype} array of rank '
                            f'{ndim}, got {getattr(array, "dtype", type(array))} '
                            f'{getattr(array, "shape", "")}')


#: How a guard names each dtype (``_guards.py`` binds these names to numpy dtypes).
DTYPE_NAMES = {'float64': 'F8', 'int64': 'I8', 'bool': 'B1'}


def guard_source(name, signature):
    """Return the Python source of kernel ``name``'s guard, for ``_guards.py``.

    The build writes every exported kernel's guard into one module, so nothing is
    generated at import.  The check runs on every call, so its common case is one
    expression (identity of the dtype, rank, contiguity: ~0.1 us per array); anything
    it does not recognise goes to ``check_arguments``, which compares dtypes by
    equality and raises.  ``guard.unchecked`` is the compiled function itself.
    """
    checks = argument_checks(signature)
    names = [f'a{index}' for index in range(len(checks))]
    tests = ['True']
    for argument, check in zip(names, checks):
        if check is not None:
            dtype, ndim, contiguous = check
            tests.append(f'{argument}.__class__ is ndarray and {argument}.dtype is '
                         f'{DTYPE_NAMES[dtype.name]} and {argument}.ndim == {ndim}'
                         + (f' and {argument}.flags.c_contiguous' if contiguous else ''))
    arguments = ', '.join(names)
    return (f'def {name}({arguments}):\n'
            f'    if not ({" and ".join(tests)}):\n'
            f'        from polyc2bf_ros.core.kernels.jit import argument_checks, '
            f'check_arguments\n'
            f'        check_arguments({name!r}, argument_checks({signature!r}), '
            f'({arguments},))\n'
            f'    return _kernels.{name}({arguments})\n'
            f'\n\n'
            f'{name}.unchecked = _kernels.{name}\n')


def _njit(function, **options):
    """Return ``function`` compiled by numba on first call (and cached on disk)."""
    import numba
    return numba.njit(**JIT_OPTIONS, **options)(function)


def kernel(signature_or_helper):
    """Decorate a kernel: ``@kernel(signature(...))`` exported, bare ``@kernel`` a helper.

    Ahead of time, an exported kernel is the extension's compiled function
    (guarded) and a helper stays Python (the compiled kernels contain it).
    """
    if callable(signature_or_helper):
        if AHEAD_OF_TIME is not None:
            return signature_or_helper
        return _njit(signature_or_helper, inline='always')
    signature = signature_or_helper

    def decorate(function):
        name = export_name(function.__module__, function.__name__)
        if AHEAD_OF_TIME is not None:
            from polyc2bf_ros.core.kernels import _guards
            return getattr(_guards, name)
        compiled = _njit(function)
        compiled.unchecked = compiled  # numba checks types itself
        EXPORTS[name] = (compiled, signature)
        return compiled
    return decorate

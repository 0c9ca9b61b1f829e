"""Compile the core's exported kernels ahead of time into ``core/kernels/_kernels*.so``.

    python -m polyc2bf_ros.core.kernels.build

Imports every core module with ``POLYC2BF_KERNELS=jit`` (so each exported
kernel registers itself in ``jit.EXPORTS`` with its signature), compiles them
into one extension module with numba's ``pycc`` for a generic CPU of this
architecture (as fast here as tuning for the host, and safe to copy), and
writes beside it the kernels' argument guards (``_guards.py``) and the digest of
their sources (``jit`` uses the extension only while the digest matches).  Each
export is a thin function calling the numba kernel, so the kernel keeps its
``error_model='numpy'`` and the helpers it calls.
Needs numba and a C compiler; takes about a minute.
"""
import importlib
import os
import pkgutil
import sys
import tempfile
import time
import warnings


def _forwarder(kernel, arity):
    """Return a Python function of ``arity`` arguments that returns ``kernel(*arguments)``."""
    names = ', '.join(f'a{i}' for i in range(arity))
    namespace = {'kernel': kernel}
    exec(f'def forward({names}):\n    return kernel({names})\n', namespace)  # noqa: S102
    return namespace['forward']


GUARDS_HEADER = """\"\"\"Argument guards of the ahead-of-time kernels (from ``kernels.build``).

Do not edit.  One function per exported kernel (``jit.guard_source``): it checks dtype, rank and
contiguity of every array argument, then calls the compiled kernel.
\"\"\"
from numpy import dtype, ndarray

from polyc2bf_ros.core.kernels import _kernels

F8, I8, B1 = dtype('float64'), dtype('int64'), dtype('bool')
"""


def write_guards(path, jit):
    """Write the guards of every kernel in ``jit.EXPORTS`` into ``path``."""
    functions = [jit.guard_source(name, signature)
                 for name, (_, signature) in sorted(jit.EXPORTS.items())]
    path.write_text(GUARDS_HEADER + ''.join(f'\n\n{source}' for source in functions))


def build(verbose=True):
    """Compile every exported kernel with a fresh numba cache; return the extension's path.

    Not the on-disk cache: it keeps a kernel compiled with an older version of a helper
    from another file (numba checks only the kernel's own file).
    """
    with tempfile.TemporaryDirectory(prefix='polyc2bf_kernels_') as cache:
        os.environ['NUMBA_CACHE_DIR'] = cache
        return _compile(verbose)


def _compile(verbose):
    os.environ['POLYC2BF_KERNELS'] = 'jit'
    import polyc2bf_ros.core as core
    from polyc2bf_ros.core.kernels import jit
    if jit.AHEAD_OF_TIME is not None:
        raise RuntimeError('polyc2bf_ros.core.kernels.jit was imported in ahead-of-time mode '
                           'before the build; run the build in a fresh process')
    for module in pkgutil.walk_packages(core.__path__, f'{core.__name__}.'):
        if module.name.rsplit('.', 1)[-1] not in ('build', '_kernels', '_guards'):
            importlib.import_module(module.name)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')  # pycc is pending deprecation in numba
        from numba.pycc import CC
    compiler = CC('_kernels')
    compiler.output_dir = str(jit.KERNELS)
    compiler.target_cpu = 'generic'  # runs on any x86-64 (no host-only instructions)
    compiler.verbose = False
    for name, (kernel, signature) in sorted(jit.EXPORTS.items()):
        arity = len(jit.argument_checks(signature))
        compiler.export(name, signature)(_forwarder(kernel, arity))
    start = time.perf_counter()
    if verbose:
        print(f'compiling {len(jit.EXPORTS)} kernels ahead of time into '
              f'{jit.KERNELS}/_kernels*.so', flush=True)
    compiler.compile()
    write_guards(jit.KERNELS / '_guards.py', jit)
    jit.DIGEST_FILE.write_text(jit.source_digest() + '\n')
    if verbose:
        print(f'done in {time.perf_counter() - start:.0f} s', flush=True)
    return compiler.output_file


if __name__ == '__main__':
    sys.exit(0 if build() else 1)

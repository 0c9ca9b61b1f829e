"""Kernels ahead of time (numba ``pycc``) against ``njit(cache=True)`` with a warm cache.

Usage: python bench/bench_kernels.py [--rounds 5] [--steps 2000] [--obstacles 50]
       [--tree /tmp/kbench] [--reuse] [--no-cold] [--out bench/results/kernels.json]

numba has deprecated ``pycc``, which builds the filter's kernels ahead of time
(``polyc2bf_ros.core.kernels.jit``, ``POLYC2BF_KERNELS``).  This measures the two ways
to run them, each in fresh processes, paired and interleaved (aot, jit, aot,
jit, ... for ``--rounds`` rounds; medians reported, with the ratio jit / aot):

- ``aot``: the extension ``core/kernels/_kernels*.so`` built by ``kernels.build``;
- ``jit``: ``numba.njit(cache=True)`` with numba's on-disk cache (``__pycache__``
  beside the sources) filled beforehand, as a warm-up at install would.

Each process builds the node's default filter (``filter_parameters.build_filter``:
unicycle, 100 Hz) and steps it as ``bench_core.py`` does (its unicycle case and
its ``--obstacles`` 8-gons).  Per process: the interpreter's start (``python_s``),
the import of the filter's module (``import_s``), wall time from the spawn to the
first step's answer (``first_step_s``) and to the end (``total_s``); VmRSS and
VmHWM after the first step and after ``--steps`` more; p50 / p99 / max of those
steps and which step was the slowest (``step_max_at``); whether numba / llvmlite
were imported; which mode ``jit`` really chose (``jit.AHEAD_OF_TIME``), which is
checked against the one asked for.  A jit process that changed the cache
(compiled something) is flagged ``compiled``.

Setup, timed once: the ahead-of-time build (``build_s``); a jit process with an
empty cache (``jit_cold``: what a first start costs without a warm-up); the
warm-up an install could run, ``safety_filter.compile_kernels()`` (one filter per
model and barrier), on an empty cache, then a jit process after it (``cache
files written`` says what that warm-up missed).

Everything runs in a private copy of the repository's HEAD (``git archive`` into
``--tree``, which this script owns: it only deletes a tree it made), with the
processes' working directory there so that copy is imported (checked), its own
build and its own numba cache: edits to the checkout and its build cannot
interfere.  The checkout's own build is only checked (``checkout_aot``: does
``POLYC2BF_KERNELS=aot`` load it, i.e. does its digest match the sources).

Records (``bench`` ``kernels_run``: one process; ``kernels``: medians of a mode;
``kernels``, modes ``ratio_jit_over_aot`` and ``paired_ratio_jit_over_aot``: the
ratio of the medians, and the median of each round's ratio; ``kernels_setup``: build
and warm-up times) carry the load average: the numbers are wall times on a shared VM.
"""
import argparse
import importlib.metadata
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

from bench_io import write_records

REPO = Path(__file__).resolve().parents[1]
# The modules the processes use, by name (the only places to update when they move).
FILTER_MODULE = 'polyc2bf_ros.core.safety_filter'
JIT_MODULE = 'polyc2bf_ros.core.kernels.jit'
BUILD_MODULE = 'polyc2bf_ros.core.kernels.build'
MODES = ('aot', 'jit')
TREE_MARKER = '.bench_kernels_tree'
TIMEOUT_S = 1800

CHILD = """
import time
entered = time.monotonic()
import importlib
import json
import sys
spawned, steps, count = float(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
filter_module, jit_module, bench_dir = sys.argv[4:7]
importlib.import_module(filter_module)
imported = time.monotonic()
jit = importlib.import_module(jit_module)
import numpy as np
import polyc2bf_ros
from polyc2bf_ros.filter_parameters import build_filter
sys.path.insert(0, bench_dir)
from bench_core import CASES, octagons, rk4_step  # bench_core's case, layout and physics


def memory():
    fields = dict(line.split(':', 1) for line in open('/proc/self/status'))
    return [int(fields[name].split()[0]) / 1024 for name in ('VmRSS', 'VmHWM')]


command_filter = build_filter({}).command_filter  # the node's default filter
safety_filter, model = command_filter.safety_filter, command_filter.model
start, goal, controller, period, substeps = CASES[model.name]
obstacles = octagons(count, np.random.default_rng([7, 0, count]))  # bench_core's unicycle seed
x = start.copy()
u, info = safety_filter.step(x, obstacles, controller(x, goal))
first = time.monotonic()
rss_first, hwm_first = memory()
numba_first = 'numba' in sys.modules
samples = np.empty(steps)
statuses = {}
for i in range(steps):
    for _ in range(substeps):
        x = rk4_step(model, x, u, period / substeps)
    u_nom = controller(x, goal)
    begin = time.perf_counter()
    u, info = safety_filter.step(x, obstacles, u_nom, obstacle_age=i * period)
    samples[i] = time.perf_counter() - begin
    statuses[info.status.value] = statuses.get(info.status.value, 0) + 1
end = time.monotonic()
rss_end, hwm_end = memory()
us = samples * 1e6
print(json.dumps({
    'mode_active': 'aot' if jit.AHEAD_OF_TIME is not None else 'jit',
    'kernels_file': getattr(jit.AHEAD_OF_TIME, '__file__', None),
    'package_file': polyc2bf_ros.__file__, 'model': model.name,
    'python_s': entered - spawned, 'import_s': imported - entered,
    'first_step_s': first - spawned, 'total_s': end - spawned,
    'rss_first_mb': rss_first, 'hwm_first_mb': hwm_first,
    'rss_end_mb': rss_end, 'hwm_end_mb': hwm_end,
    'step_p50_us': float(np.percentile(us, 50)), 'step_p99_us': float(np.percentile(us, 99)),
    'step_max_us': float(us.max()), 'step_max_at': int(us.argmax()), 'statuses': statuses,
    'numba_first': numba_first, 'numba_end': 'numba' in sys.modules,
    'llvmlite_end': 'llvmlite' in sys.modules}))
"""

WARM_UP = f"""
import importlib
importlib.import_module({FILTER_MODULE!r}).compile_kernels()
"""

CHECK_AOT = f"""
import importlib
print(importlib.import_module({JIT_MODULE!r}).AHEAD_OF_TIME.__file__)
"""

# (key, label, format) of the table; medians over the rounds.
METRICS = (('python_s', 'interpreter start [s]', '.3f'),
           ('import_s', f'import {FILTER_MODULE.rsplit(".", 1)[-1]} [s]', '.3f'),
           ('first_step_s', 'spawn to first step [s]', '.3f'),
           ('total_s', 'spawn to end [s]', '.2f'),
           ('rss_first_mb', 'VmRSS after first step [MB]', '.1f'),
           ('hwm_first_mb', 'VmHWM after first step [MB]', '.1f'),
           ('rss_end_mb', 'VmRSS after the steps [MB]', '.1f'),
           ('hwm_end_mb', 'VmHWM after the steps [MB]', '.1f'),
           ('step_p50_us', 'step p50 [us]', '.1f'),
           ('step_p99_us', 'step p99 [us]', '.1f'),
           ('step_max_us', 'step max [us]', '.1f'))
FLAGS = ('numba_first', 'numba_end', 'llvmlite_end')


def environment(mode=None):
    """Return the processes' environment: numba's default cache, ``POLYC2BF_KERNELS=mode``."""
    env = {name: value for name, value in os.environ.items()
           if name not in ('NUMBA_CACHE_DIR', 'POLYC2BF_KERNELS', 'PYTHONPATH')}
    if mode is not None:
        env['POLYC2BF_KERNELS'] = mode
    return env


def run(arguments, cwd, mode=None):
    """Run ``python arguments`` in ``cwd``; return (stdout, wall seconds); exit on failure."""
    begin = time.monotonic()
    result = subprocess.run([sys.executable, *arguments], cwd=cwd, env=environment(mode),
                            capture_output=True, text=True, timeout=TIMEOUT_S)
    seconds = time.monotonic() - begin
    if result.returncode != 0:
        sys.exit(f'{" ".join(arguments)[:60]} (POLYC2BF_KERNELS={mode}, in {cwd}) failed:\n'
                 f'{result.stderr[-2000:]}')
    return result.stdout, seconds


def load():
    """Return the 1-minute load average, rounded."""
    return round(os.getloadavg()[0], 2)


def prepare_tree(tree):
    """Replace ``tree`` by ``git archive HEAD`` of the repository; return the commit."""
    if tree.exists():
        if not (tree / TREE_MARKER).is_file():
            sys.exit(f'{tree} exists and was not made by this benchmark: choose another --tree')
        shutil.rmtree(tree)
    tree.mkdir(parents=True)
    commit = subprocess.run(['git', '-C', str(REPO), 'rev-parse', 'HEAD'], check=True,
                            capture_output=True, text=True).stdout.strip()
    archive = subprocess.Popen(['git', '-C', str(REPO), 'archive', commit],
                               stdout=subprocess.PIPE)
    subprocess.run(['tar', '-x', '-C', str(tree)], stdin=archive.stdout, check=True)
    archive.stdout.close()
    if archive.wait() != 0:
        sys.exit('git archive failed')
    (tree / TREE_MARKER).write_text(commit + '\n')
    return commit


def cache_files(tree):
    """Return {path: mtime_ns} of numba's cache files (index and data) under ``tree``."""
    return {str(path): path.stat().st_mtime_ns for pattern in ('*.nbi', '*.nbc')
            for path in (tree / 'polyc2bf_ros').rglob(pattern)}


def clear_cache(tree):
    """Delete numba's cache files under ``tree``."""
    for path in cache_files(tree):
        Path(path).unlink()


def child(tree, mode, steps, count):
    """Run one measuring process in ``tree``; return its record (exit if the mode is wrong)."""
    before = cache_files(tree)
    stdout, _ = run(['-c', CHILD, repr(time.monotonic()), str(steps), str(count),
                     FILTER_MODULE, JIT_MODULE, str(tree / 'bench')], tree, mode)
    record = json.loads(stdout.splitlines()[-1])
    after = cache_files(tree)
    written = sorted(Path(path).name for path, stamp in after.items()
                     if before.get(path) != stamp)
    if record['mode_active'] != mode:
        sys.exit(f'asked for POLYC2BF_KERNELS={mode}, the process ran {record["mode_active"]}')
    if not record['package_file'].startswith(str(tree)):
        sys.exit(f'the process imported {record["package_file"]}, not the copy in {tree}')
    if mode == 'aot' and not str(record['kernels_file']).startswith(str(tree)):
        sys.exit(f'the process loaded the kernels {record["kernels_file"]}, not the copy\'s')
    record.update(mode=mode, cache_files_written=len(written), compiled=bool(written),
                  cache_file_names=[name for name in written if name.endswith('.nbi')],
                  load_avg_1min=load())
    return record


def checkout_aot():
    """Return whether the checkout's own build loads with ``POLYC2BF_KERNELS=aot``, and why not."""
    result = subprocess.run([sys.executable, '-c', CHECK_AOT], cwd=REPO,
                            env=environment('aot'), capture_output=True, text=True,
                            timeout=TIMEOUT_S)
    if result.returncode == 0:
        return 'loads (digest matches)'
    return 'fails: ' + (result.stderr.strip().splitlines() or ['?'])[-1][:200]


def setup(tree, args):
    """Copy, build and warm; return the setup record (timings of the build and warm-ups)."""
    record = {'bench': 'kernels_setup', 'tree': str(tree), 'checkout_aot': checkout_aot()}
    print(f'checkout {REPO}: POLYC2BF_KERNELS=aot {record["checkout_aot"]}', flush=True)
    if args.reuse:
        record['commit'] = (tree / TREE_MARKER).read_text().strip()
    else:
        record['commit'] = prepare_tree(tree)
        print(f'copied HEAD {record["commit"][:10]} to {tree}; building ahead of time', flush=True)
        record['load_before_build'] = load()
        _, record['build_s'] = run(['-m', BUILD_MODULE], tree)
        print(f'ahead-of-time build: {record["build_s"]:.1f} s (load {load()})', flush=True)
    if not args.no_cold:
        clear_cache(tree)
        cold = child(tree, 'jit', args.steps, args.obstacles)
        record.update(jit_cold_first_step_s=cold['first_step_s'], jit_cold_total_s=cold['total_s'],
                      jit_cold_cache_files=cold['cache_files_written'],
                      jit_cold_hwm_mb=cold['hwm_end_mb'], load_after_cold=load())
        print(f'jit, empty cache: first step after {cold["first_step_s"]:.1f} s, whole run '
              f'{cold["total_s"]:.1f} s, {cold["cache_files_written"]} cache files written, '
              f'VmHWM {cold["hwm_end_mb"]:.0f} MB (load {load()})', flush=True)
        clear_cache(tree)
        _, record['warm_up_compile_kernels_s'] = run(['-c', WARM_UP], tree, 'jit')
        record['warm_up_cache_files'] = len(cache_files(tree))
        print(f'warm-up compile_kernels(), empty cache: {record["warm_up_compile_kernels_s"]:.1f}'
              f' s, {record["warm_up_cache_files"]} cache files (load {load()})', flush=True)
    after = child(tree, 'jit', args.steps, args.obstacles)  # fills what is left of the cache
    record.update(after_warm_up_first_step_s=after['first_step_s'],
                  after_warm_up_cache_files_written=after['cache_files_written'],
                  after_warm_up_compiled=after['cache_file_names'])
    print(f'jit after the warm-up: first step after {after["first_step_s"]:.2f} s, '
          f'{after["cache_files_written"]} cache files written {after["cache_file_names"]}',
          flush=True)
    child(tree, 'aot', args.steps, args.obstacles)  # the extension and sources into page cache
    record['load_avg_1min'] = load()
    return record


def summary(runs):
    """Return one record per mode with the medians of its runs, and the ratio jit / aot."""
    records = []
    for mode in MODES:
        mine = [r for r in runs if r['mode'] == mode]
        record = {'bench': 'kernels', 'mode': mode if mode == 'aot' else 'jit_warm_cache',
                  'rounds': len(mine)}
        record.update({key: round(statistics.median(r[key] for r in mine), 4)
                       for key, _, _ in METRICS})
        record.update({flag: sorted({r[flag] for r in mine}) for flag in (*FLAGS, 'compiled')})
        record['load_avg_1min'] = round(statistics.median(r['load_avg_1min'] for r in mine), 2)
        records.append(record)
    aot, jit = records
    ratios = {'bench': 'kernels', 'mode': 'ratio_jit_over_aot'}
    ratios.update({key: round(jit[key] / aot[key], 3) for key, _, _ in METRICS if aot[key]})
    pairs = list(zip(*([r for r in runs if r['mode'] == mode] for mode in MODES)))
    paired = {'bench': 'kernels', 'mode': 'paired_ratio_jit_over_aot', 'rounds': len(pairs)}
    paired.update({key: round(statistics.median(j[key] / a[key] for a, j in pairs), 3)
                   for key, _, _ in METRICS if all(a[key] for a, _ in pairs)})
    return [*records, ratios, paired]


def print_table(records):
    """Print the medians of both modes and their ratio."""
    aot, jit, ratio, paired = records
    print(f'\nmedians of {aot["rounds"]} paired rounds (jit/aot: of the medians; paired: '
          "median of the rounds' ratios)")
    print(f'{"":<30} {"aot":>10} {"jit warm":>10} {"jit/aot":>8} {"paired":>7}')
    for key, label, form in METRICS:
        print(f'{label:<30} {aot[key]:>10{form}} {jit[key]:>10{form}} {ratio.get(key, 0):>8.2f}'
              f' {paired.get(key, 0):>7.2f}')
    for flag in (*FLAGS, 'compiled'):
        print(f'{flag:<30} {str(aot[flag]):>10} {str(jit[flag]):>10}')


def main(argv=None):
    """Set up, run the paired rounds, print the table and write the JSON records."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--rounds', type=int, default=5)
    parser.add_argument('--steps', type=int, default=2000)
    parser.add_argument('--obstacles', type=int, default=50)
    parser.add_argument('--tree', type=Path, default=Path('/tmp/kbench'),
                        help='private copy of HEAD to measure in (made by this benchmark)')
    parser.add_argument('--reuse', action='store_true',
                        help='reuse --tree and its build (no copy, no build)')
    parser.add_argument('--no-cold', action='store_true',
                        help='skip the empty-cache jit run and the compile_kernels warm-up')
    parser.add_argument('--out', default='bench/results/kernels.json')
    args = parser.parse_args(argv)
    tree = args.tree.resolve()
    if args.reuse and not (tree / TREE_MARKER).is_file():
        sys.exit(f'--reuse: {tree} is no tree of this benchmark')
    print(f'load average at start: {" ".join(f"{v:.2f}" for v in os.getloadavg())}; '
          f'{os.cpu_count()} CPUs; numba {importlib.metadata.version("numba")}', flush=True)
    records = [setup(tree, args)]
    runs = []
    print(f'{"round":>5} {"mode":>4} {"import s":>8} {"first s":>8} {"RSS1 MB":>8} '
          f'{"RSS MB":>7} {"p50 us":>7} {"p99 us":>7} {"numba":>5} {"load":>5}')
    for index in range(args.rounds):
        for mode in MODES:
            record = child(tree, mode, args.steps, args.obstacles)
            record.update(bench='kernels_run', round=index, steps=args.steps,
                          obstacles=args.obstacles)
            runs.append(record)
            print(f'{index:>5} {mode:>4} {record["import_s"]:>8.3f} '
                  f'{record["first_step_s"]:>8.3f} {record["rss_first_mb"]:>8.1f} '
                  f'{record["rss_end_mb"]:>7.1f} {record["step_p50_us"]:>7.1f} '
                  f'{record["step_p99_us"]:>7.1f} {str(record["numba_end"]):>5} '
                  f'{record["load_avg_1min"]:>5.2f}'
                  + ('  (compiled!)' if record['compiled'] else ''), flush=True)
    medians = summary(runs)
    print_table(medians)
    print(f'load average at end: {" ".join(f"{v:.2f}" for v in os.getloadavg())}')
    write_records([*records, *medians, *runs], args.out)


if __name__ == '__main__':
    main()

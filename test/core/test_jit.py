"""Kernels ahead of time: in use after the build, guarded, never stale, same answers as numba."""
import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from polyc2bf_ros.core.barrier.cone_models import CONE_MODELS
from polyc2bf_ros.core.geometry.polygons import convex_hull
from polyc2bf_ros.core.kernels import jit
from polyc2bf_ros.core.kernels.views import _viewpoints
from polyc2bf_ros.core.models import make_model, MODEL_NAMES
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.core.safety_filter import FilterConfig, SafetyFilter
from strategies import random_state

REPO = Path(__file__).resolve().parents[2]
needs_build = pytest.mark.skipif(jit.AHEAD_OF_TIME is None, reason='kernels not built')


@pytest.mark.skipif(not jit.DIGEST_FILE.exists(),
                    reason='no ahead-of-time build (make warned): the kernels run just in time')
def test_the_built_kernels_are_in_use():
    """A build (make runs it) is in use: the suite runs what users run, without numba."""
    assert os.environ.get(jit.MODE_VARIABLE, 'auto') != 'jit'
    assert jit.AHEAD_OF_TIME is not None, \
        'run: python -m polyc2bf_ros.core.kernels.build (make does)'
    assert _viewpoints.__name__ == 'core_kernels_views__viewpoints'
    assert hasattr(_viewpoints, 'unchecked')


@needs_build
@pytest.mark.parametrize('bad, what', [
    (np.zeros((3, 2), dtype=np.float32), 'float32'),
    (np.zeros((3, 4))[:, :2], 'strided'),
    (np.zeros(6), 'rank'),
    ([[0.0, 0.0]] * 3, 'list'),
])
def test_guard_refuses_arrays_compiled_code_would_misread(bad, what):
    """Wrong dtype, layout, rank or type: TypeError naming the kernel and argument."""
    projections = np.zeros((3, 2, 2))
    with pytest.raises(TypeError, match=r'core_kernels_views__viewpoints: argument 2 must be'):
        _viewpoints(projections, np.zeros(2), bad, np.zeros((3, 2)), 0.0, np.empty((2, 3)))


def test_argument_checks_read_numba_signatures():
    """Arrays give (dtype, rank, C-contiguous); scalars None; tuple results are skipped."""
    checks = jit.argument_checks(jit.signature('UniTuple(f8, 2)', jit.F2, 'i8', 'f8[:, :]',
                                               jit.B1))
    assert checks == ((np.dtype(np.float64), 2, True), None, (np.dtype(np.float64), 2, False),
                      (np.dtype(np.bool_), 1, True))


@pytest.mark.parametrize('mode', ['auto', 'aot'])
def test_stale_build_is_never_used(tmp_path, monkeypatch, mode):
    """Sources changed since the build (digest differs): auto warns and compiles, aot fails."""
    stale = tmp_path / '_kernels.digest'
    stale.write_text('0' * 64 + '\n')
    monkeypatch.setattr(jit, 'DIGEST_FILE', stale)
    monkeypatch.setenv(jit.MODE_VARIABLE, mode)
    if mode == 'aot':
        with pytest.raises(RuntimeError, match='other sources'):
            jit._load_ahead_of_time()
    elif jit.AHEAD_OF_TIME is not None:
        with pytest.warns(RuntimeWarning, match='compiling just in time'):
            assert jit._load_ahead_of_time() is None


def test_unknown_mode_is_refused(monkeypatch):
    """POLYC2BF_KERNELS takes auto, aot or jit."""
    monkeypatch.setenv(jit.MODE_VARIABLE, 'fast')
    with pytest.raises(ValueError, match='auto, aot, jit'):
        jit._load_ahead_of_time()


def test_jit_mode_imports_nothing_built(monkeypatch):
    """POLYC2BF_KERNELS=jit ignores the extension even when it is there."""
    monkeypatch.setenv(jit.MODE_VARIABLE, 'jit')
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        assert jit._load_ahead_of_time() is None


STEPS_SCRIPT = """
import json, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from test_jit import filter_steps
from polyc2bf_ros.core.kernels import jit
assert jit.AHEAD_OF_TIME is None
print(json.dumps(filter_steps()))
"""


def filter_steps():
    """Return u_safe, status and h of seeded steps for every model and barrier."""
    rng = np.random.default_rng(7)
    results = []
    for model_name in MODEL_NAMES:
        model = make_model(model_name)
        for barrier in sorted(CONE_MODELS):
            filt = SafetyFilter(model, FilterConfig(barrier=barrier))
            for _ in range(5):
                polygons = [convex_hull(rng.uniform(-0.4, 0.4, (6, 2))) + rng.uniform(-3, 3, 2)
                            for _ in range(4)]
                obstacles = ObstacleSet.from_obstacles([
                    Obstacle(polygon=polygon, velocity=rng.uniform(-0.5, 0.5, 3), z_min=-1.0,
                             z_max=2.0) for polygon in polygons])
                state = random_state(model_name, rng)
                u_nom = rng.uniform(model.input_lower, model.input_upper)
                u, info = filt.step(state, obstacles, u_nom, 0.01)
                results.append([u.tolist(), info.status.value, info.h.tolist()])
    return results


@needs_build
@pytest.mark.slow
def test_ahead_of_time_and_numba_give_the_same_answers(tmp_path):
    """The same steps in a process compiling with numba: identical inputs, outputs to 1e-12."""
    env = dict(os.environ, POLYC2BF_KERNELS='jit', PYTHONPATH=str(REPO))
    result = subprocess.run([sys.executable, '-c', STEPS_SCRIPT, str(Path(__file__).parent)],
                            env=env, cwd=tmp_path, capture_output=True, text=True, timeout=300,
                            check=True)
    numba_steps = json.loads(result.stdout.splitlines()[-1])
    built_steps = filter_steps()
    assert len(numba_steps) == len(built_steps) == len(MODEL_NAMES) * len(CONE_MODELS) * 5
    for (u_numba, status_numba, h_numba), (u_built, status_built, h_built) in zip(numba_steps,
                                                                              built_steps):
        assert status_numba == status_built
        np.testing.assert_allclose(u_built, u_numba, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(h_built, h_numba, rtol=1e-12, atol=1e-12)


def test_every_kernel_lives_in_the_kernels_folder():
    """No file of the package outside ``core/kernels`` defines a kernel: the digest covers all."""
    package = REPO / 'polyc2bf_ros'
    outside = [f'{path.relative_to(REPO)}:{number}'
               for path in sorted(package.rglob('*.py')) if jit.KERNELS not in path.parents
               for number, line in enumerate(path.read_text().splitlines(), 1)
               if line.startswith('@kernel')]
    assert outside == []
    assert all(path.parent == jit.KERNELS for path in jit.kernel_sources())

"""The benchmarks' check that the installed packages are this checkout's (bench/bench_io.py)."""
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / 'bench'))
from bench_io import differing_sources, require_installed_checkout  # noqa: E402


def _tree(root, files):
    for relative, text in files.items():
        path = root / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


def test_differing_sources_lists_changed_and_missing_files(tmp_path):
    """Changed and missing sources are listed; extra or non-Python files are not."""
    files = {'a.py': 'x = 1\n', 'sub/b.py': 'y = 2\n', 'sub/c.py': 'z = 3\n'}
    source = _tree(tmp_path / 'source', files)
    installed = _tree(tmp_path / 'installed', {**files, 'sub/b.py': 'y = 20\n', 'extra.py': ''})
    (installed / 'sub' / 'c.py').unlink()
    (installed / 'data.txt').write_text('not a source')
    assert differing_sources(source, installed) == ['sub/b.py', 'sub/c.py']
    assert differing_sources(source, source) == []
    assert differing_sources(source, tmp_path / 'nowhere') == ['a.py', 'sub/b.py', 'sub/c.py']


def test_require_installed_checkout_names_the_fix(tmp_path):
    """A differing checkout exits naming the file and `make venv`; the same tree passes."""
    import polyc2bf_ros
    imported = Path(polyc2bf_ros.__file__).parent
    checkout = _tree(tmp_path / 'repo', {'polyc2bf_ros/__init__.py': '# edited\n'})
    with pytest.raises(SystemExit, match=r'polyc2bf_ros/__init__\.py.*make venv'):
        require_installed_checkout(repo=checkout, packages=('polyc2bf_ros',))
    require_installed_checkout(repo=imported.parent, packages=('polyc2bf_ros',))


def test_a_benchmark_refuses_a_stale_install(tmp_path):
    """Run as a user would, from a copy of bench/ beside an edited package source."""
    repo = tmp_path / 'repo'
    for name in ('bench_io.py', 'bench_clutter.py'):
        _tree(repo / 'bench', {name: (REPO / 'bench' / name).read_text()})
    _tree(repo, {'polyc2bf_ros/__init__.py': '# edited after make venv\n',
                 'sim_bridge/__init__.py': (REPO / 'sim_bridge' / '__init__.py').read_text()})
    result = subprocess.run([sys.executable, str(repo / 'bench' / 'bench_clutter.py')],
                            capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert result.returncode != 0
    assert 'make venv' in result.stderr and 'polyc2bf_ros/__init__.py' in result.stderr

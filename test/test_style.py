"""Style is part of the suite: ruff with the repository's ruff.toml must pass.

The rules (pycodestyle, pyflakes, pep257 docstrings, import order, single
quotes, 99 columns) live in ``ruff.toml``; most findings are fixed with
``.venv/bin/ruff check --fix <file>``.
"""
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RUFF = [sys.executable, '-m', 'ruff', 'check', '--no-cache', '--output-format', 'concise']


def _ruff(*args, stdin=None):
    return subprocess.run([*RUFF, *args], cwd=REPO, input=stdin, capture_output=True,
                          text=True, timeout=120)


def test_repository_passes_ruff():
    """Every Python file in the repository (outside build trees) passes ruff."""
    proc = _ruff('.')
    assert proc.returncode == 0, f'ruff found style problems:\n{proc.stdout}{proc.stderr}'


def test_ruff_config_enforces_project_rules():
    """The config really enables the promised rules: a bad snippet trips each of them."""
    snippet = '\n'.join([
        'import sys',
        'import os',
        '',
        '',
        'def public():',
        '    return "double" + os.sep + sys.platform + ' + repr('x' * 60),
        '',
    ])
    proc = _ruff('--stdin-filename', 'polyc2bf_ros/style_probe.py', '-', stdin=snippet)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    for code in ('I001', 'D100', 'D103', 'Q000', 'E501'):
        assert code in proc.stdout, f'{code} not reported:\n{proc.stdout}'

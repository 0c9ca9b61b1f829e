"""package.xml declares exactly what the shipped code imports, and the locks are split."""
import ast
import sys
import xml.etree.ElementTree as ElementTree
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHIPPED = ('polyc2bf_ros', 'sim_bridge', 'launch')
OWN = {'polyc2bf_ros', 'sim_bridge'}
# Third-party Python modules -> their rosdep keys.
PYTHON_KEYS = {'numpy': 'python3-numpy', 'numba': 'python3-numba', 'yaml': 'python3-yaml',
               'matplotlib': 'python3-matplotlib', 'pybullet': 'python3-pybullet',
               'pybullet_data': 'python3-pybullet', 'mcap': 'python3-mcap',
               'rosbags': 'python3-rosbags-pip', 'daqp': 'python3-daqp-pip',
               'proxsuite': 'proxsuite', 'scipy': 'python3-scipy'}


def _imported_modules():
    """Return the top-level names every shipped module imports (at any depth)."""
    names = set()
    for folder in SHIPPED:
        for path in (REPO / folder).rglob('*.py'):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Import):
                    names |= {alias.name.split('.')[0] for alias in node.names}
                elif isinstance(node, ast.ImportFrom) and node.level == 0:
                    names.add(node.module.split('.')[0])
    return names - OWN - set(sys.stdlib_module_names)


def test_exec_depends_are_exactly_the_imports():
    """Every import has its exec_depend (ROS packages by name), and nothing else is declared."""
    root = ElementTree.parse(REPO / 'package.xml').getroot()
    declared = {e.text for e in root.findall('exec_depend')}
    imported = _imported_modules()
    unknown = imported - set(PYTHON_KEYS) - {m for m in imported if m in declared}
    assert not unknown, f'imports without an exec_depend: {sorted(unknown)}'
    expected = {PYTHON_KEYS.get(name, name) for name in imported}
    assert declared == expected, (sorted(declared - expected), sorted(expected - declared))


def test_runtime_and_development_pins_are_split():
    """No development tool in the runtime lock; no package pinned in both."""
    def pins(name):
        lines = (REPO / name).read_text().splitlines()
        return {line.split('==')[0].lower() for line in lines if '==' in line}

    runtime, development = pins('requirements.lock'), pins('requirements-dev.lock')
    assert not runtime & development
    assert {'pytest', 'hypothesis', 'ruff', 'colcon-core'} <= development
    assert not {'pytest', 'hypothesis', 'ruff', 'coverage'} & runtime

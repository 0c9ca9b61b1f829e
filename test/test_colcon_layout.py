"""``colcon build`` produces the install tree that ``ros2 run`` / ``ros2 launch`` resolve.

The package is built once per test run (shared by the xdist workers through a
file lock) into a temporary directory: build, install and log trees never land
in the checkout.  The tests then check the install layout against ``setup.py``
and start the installed ``safety_filter`` the way ``ros2 run`` would after
``source install/local_setup.sh``, with ``--ros-args`` namespace and node-name
remapping, and watch it on the ROS graph over real DDS.

Clean shutdown, as decided here: after SIGINT (Ctrl-C, or what ``ros2 launch``
sends first) the node must exit within ``SHUTDOWN_TIMEOUT_S`` with return code 0
(the usual ``except (KeyboardInterrupt, ExternalShutdownException)`` in ``main``)
or by re-raising SIGINT (return code -2, shown as 130 by a shell), and must not
print a Python traceback.
"""
import ast
import configparser
import fcntl
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rclpy

REPO = Path(__file__).resolve().parents[1]
PACKAGE = 'polyc2bf_ros'
BUILD_TIMEOUT_S = 600
GRAPH_TIMEOUT_S = 30.0
SHUTDOWN_TIMEOUT_S = 15.0
# Absolute topics a node may use besides its own (relative, namespaced) ones.
GLOBAL_TOPICS = {'/rosout', '/parameter_events', '/diagnostics', '/clock', '/tf', '/tf_static'}

# Every test here needs the colcon build (about 5 s alone, more on a busy machine).
pytestmark = pytest.mark.slow


def _console_scripts():
    """Return ``{name: 'module:function'}`` from ``CONSOLE_SCRIPTS`` in setup.py."""
    tree = ast.parse((REPO / 'setup.py').read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == 'CONSOLE_SCRIPTS' for t in node.targets):
            entries = ast.literal_eval(node.value)
            return dict((part.strip() for part in e.split('=', 1)) for e in entries)
    raise AssertionError('setup.py no longer defines CONSOLE_SCRIPTS; update this test')


def _colcon_build(root):
    """Run colcon into ``root``; return a JSON-able record of what happened."""
    env = {k: v for k, v in os.environ.items()
           if k not in ('AMENT_PREFIX_PATH', 'COLCON_PREFIX_PATH', 'CMAKE_PREFIX_PATH')}
    env['COLCON_HOME'] = str(root / 'colcon_home')  # no user defaults/mixins
    env['COLCON_LOG_PATH'] = str(root / 'log')
    repo_entries = set(os.listdir(REPO))
    cmd = [sys.executable, '-m', 'colcon', '--log-base', str(root / 'log'), 'build',
           '--base-paths', str(REPO),
           '--build-base', str(root / 'build'),
           '--install-base', str(root / 'install'),
           '--merge-install']
    started = time.monotonic()
    proc = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True,
                          timeout=BUILD_TIMEOUT_S)
    return {
        'cmd': cmd,
        'returncode': proc.returncode,
        'output': (proc.stdout + proc.stderr)[-6000:],
        'seconds': time.monotonic() - started,
        'new_repo_entries': sorted(set(os.listdir(REPO)) - repo_entries),
    }


@pytest.fixture(scope='session')
def colcon_tree(tmp_path_factory):
    """Build once per run; xdist workers share one build through a lock file."""
    if os.environ.get('PYTEST_XDIST_WORKER'):
        shared = tmp_path_factory.getbasetemp().parent  # this run's dir, common to workers
    else:
        shared = tmp_path_factory.getbasetemp()
    root = shared / 'colcon'
    record_file = shared / 'colcon-build.json'
    with open(shared / 'colcon-build.lock', 'w') as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not record_file.exists():
            root.mkdir(exist_ok=True)
            record_file.write_text(json.dumps(_colcon_build(root)))
    record = json.loads(record_file.read_text())
    assert record['returncode'] == 0, f'colcon build failed:\n{record["output"]}'
    return root, record


def _installed_env(install):
    """Return the environment ``. install/local_setup.sh`` gives, as ``ros2 run`` would see."""
    proc = subprocess.run(['sh', '-c', '. "$1/local_setup.sh" && env -0', 'sh', str(install)],
                          capture_output=True, timeout=60, check=True)
    return dict(item.split('=', 1) for item in proc.stdout.decode().split('\0') if '=' in item)


def test_build_stays_out_of_the_checkout(colcon_tree):
    """Colcon's build, install and log trees are in tmp, none appeared in the repository."""
    root, record = colcon_tree
    assert not set(record['new_repo_entries']) & {'build', 'install', 'log'}, record
    for tree in ('build', 'install', 'log'):
        assert (root / tree).is_dir() and not (root / tree).is_relative_to(REPO)


def test_every_console_script_is_installed_to_lib_package(colcon_tree):
    """``lib/polyc2bf_ros/<name>`` exists for each of setup.py's CONSOLE_SCRIPTS."""
    root, _ = colcon_tree
    scripts = _console_scripts()
    assert 'safety_filter' in scripts, scripts
    generated = configparser.ConfigParser()
    generated.read(root / 'build' / PACKAGE / f'{PACKAGE}.egg-info' / 'entry_points.txt')
    assert dict(generated['console_scripts']) == scripts
    for name in scripts:
        exe = root / 'install' / 'lib' / PACKAGE / name
        assert exe.is_file() and os.access(exe, os.X_OK), f'{exe} missing or not executable'
        # Run by the interpreter colcon ran with (the one that has rclpy).
        assert sys.executable in exe.read_text().splitlines()[0], exe.read_text()[:200]


def test_ament_index_marker_package_xml_config_and_launch_are_installed(colcon_tree):
    """What ``ros2 run``, ``ros2 pkg prefix`` and ``ros2 launch`` look up is in place."""
    root, _ = colcon_tree
    install = root / 'install'
    marker = install / 'share' / 'ament_index' / 'resource_index' / 'packages' / PACKAGE
    assert marker.is_file()
    share = install / 'share' / PACKAGE
    assert (share / 'package.xml').read_text() == (REPO / 'package.xml').read_text()
    assert (share / 'config').is_dir() and (share / 'launch').is_dir()
    for sub, pattern in (('config', '*.yaml'), ('launch', '*.py')):
        in_repo = {p.name for p in (REPO / sub).glob(pattern)}
        installed = {p.name for p in (share / sub).glob(pattern)}
        assert in_repo <= installed, (sub, in_repo - installed)
    assert (share / 'launch' / 'safety_filter.launch.py').is_file()


def test_launch_file_default_params_file_is_installed(colcon_tree):
    """``safety_filter.launch.py`` defaults to ``config/quadruped.yaml``: it must be there."""
    root, _ = colcon_tree
    launch_text = (REPO / 'launch' / 'safety_filter.launch.py').read_text()
    assert "'quadruped.yaml'" in launch_text
    installed = root / 'install' / 'share' / PACKAGE / 'config' / 'quadruped.yaml'
    assert installed.is_file(), 'config/quadruped.yaml (launch default) is not installed'


def test_every_python_package_is_installed(colcon_tree):
    """Each package directory of the checkout is installed (setup.py's ``packages``)."""
    root, _ = colcon_tree
    site = root / 'install' / 'lib' / 'python3.11' / 'site-packages'
    in_repo = {p.parent.relative_to(REPO).as_posix()
               for top in (PACKAGE, 'sim_bridge') for p in (REPO / top).rglob('__init__.py')}
    assert PACKAGE in in_repo
    missing = {pkg for pkg in in_repo if not (site / pkg / '__init__.py').is_file()}
    assert not missing, f'packages not installed (add them to setup.py): {sorted(missing)}'


def test_installed_safety_filter_honours_ros_args_remapping(colcon_tree, tmp_path):
    """``lib/polyc2bf_ros/safety_filter --ros-args -r __ns:=/robot1 -r __node:=renamed``."""
    root, _ = colcon_tree
    install = root / 'install'
    env = _installed_env(install)
    site = install / 'lib' / 'python3.11' / 'site-packages'
    assert env['PYTHONPATH'].split(os.pathsep)[0] == str(site), env.get('PYTHONPATH')
    assert str(install) in env['AMENT_PREFIX_PATH'].split(os.pathsep)
    assert env['ROS_DOMAIN_ID'] == os.environ['ROS_DOMAIN_ID']
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'

    # The installed script must import the package from the install tree, not from
    # .venv or the checkout (run outside the checkout: `python -c` puts cwd on sys.path).
    where = subprocess.run(
        [sys.executable, '-c',
         'import importlib.metadata as m, polyc2bf_ros; '
         'print(polyc2bf_ros.__file__); print(m.distribution("polyc2bf_ros").locate_file(""))'],
        env=env, cwd=tmp_path, capture_output=True, text=True, timeout=60,
        check=True).stdout.split('\n')
    assert Path(where[0]).is_relative_to(site), where
    assert Path(where[1]).is_relative_to(site), where

    exe = install / 'lib' / PACKAGE / 'safety_filter'
    stdout, stderr = open(tmp_path / 'stdout', 'w+'), open(tmp_path / 'stderr', 'w+')
    child = subprocess.Popen(
        [str(exe), '--ros-args', '-r', '__ns:=/robot1', '-r', '__node:=renamed'],
        env=env, cwd=tmp_path, stdout=stdout, stderr=stderr, text=True)

    def child_output():
        stdout.seek(0)
        stderr.seek(0)
        return f'--- stdout\n{stdout.read()[-4000:]}\n--- stderr\n{stderr.read()[-4000:]}'

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        observer = rclpy.create_node('colcon_layout_observer', context=context)
        deadline = time.monotonic() + GRAPH_TIMEOUT_S
        names, topics = [], []
        while time.monotonic() < deadline:
            assert child.poll() is None, f'safety_filter exited early ({child.returncode})\n' \
                + child_output()
            names = observer.get_node_names_and_namespaces()
            if ('renamed', '/robot1') in names:
                topics = [t for t, _ in
                          observer.get_subscriber_names_and_types_by_node('renamed', '/robot1')
                          + observer.get_publisher_names_and_types_by_node('renamed', '/robot1')]
                if {'/robot1/odom', '/robot1/obstacles'} <= set(topics):
                    break
            time.sleep(0.2)
        assert ('renamed', '/robot1') in names, f'node not on graph: {names}\n' + child_output()
        assert ('safety_filter', '/robot1') not in names, names
        # Topic names are relative: the namespace moved them under /robot1.
        assert {'/robot1/odom', '/robot1/obstacles'} <= set(topics), topics
        outside = {t for t in topics if not t.startswith('/robot1/')} - GLOBAL_TOPICS
        assert not outside, f'topics not under the namespace: {outside}'
        observer.destroy_node()
    finally:
        rclpy.shutdown(context=context)
        if child.poll() is None:
            child.send_signal(signal.SIGINT)
        try:
            returncode = child.wait(timeout=SHUTDOWN_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()
            returncode = None
    output = child_output()
    assert returncode in (0, -signal.SIGINT), f'unclean exit {returncode}\n{output}'
    assert 'Traceback' not in output, output

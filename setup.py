"""ament_python package definition for polyc2bf_ros."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'polyc2bf_ros'

# Console scripts, installed to lib/polyc2bf_ros so that `ros2 run` finds them.
# Names are the stable ones README.md lists; each is added only once it does real work.
CONSOLE_SCRIPTS = [
    'safety_filter = polyc2bf_ros.safety_filter_node:main',
    'safety_filter_lifecycle = polyc2bf_ros.safety_filter_lifecycle:main',
    'sim_bridge = sim_bridge.bridge_node:main',
    'nominal_controller = sim_bridge.nominal_controller_node:main',
    'bag_replay = sim_bridge.bag_replay:main',
    'demo = sim_bridge.demo:main',
    'evaluate = sim_bridge.evaluation.cli:main',
]

setup(
    name=PACKAGE,
    version='0.1.0',
    # polyc2bf_ros, polyc2bf_ros.core (and its subpackages) and sim_bridge.
    packages=find_packages(include=[PACKAGE, f'{PACKAGE}.*', 'sim_bridge', 'sim_bridge.*']),
    # The kernels compiled ahead of time, when built (polyc2bf_ros/core/kernels/jit.py).
    package_data={'sim_bridge': ['assets/*'],
                  f'{PACKAGE}.core.kernels': ['_kernels*.so', '_kernels.digest']},
    data_files=[
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml']),
        (f'share/{PACKAGE}/config', glob('config/*.yaml')),
        (f'share/{PACKAGE}/config/scenarios', glob('config/scenarios/*.yaml')),
        (f'share/{PACKAGE}/launch', glob('launch/*.py')),
        # BARN worlds with their licence and citation: evaluate --suite barn's default.
        (f'share/{PACKAGE}/bench/data/barn', glob('bench/data/barn/*')),
    ],
    # The filter alone; ROS 2 (rclpy and the message packages) comes from the ROS install.
    # The simulator, bag tools and plots need the `sim` extra (pip install .[sim]);
    # requirements.lock pins everything for the project's own venv.
    install_requires=['setuptools', 'numpy', 'numba', 'daqp', 'proxsuite', 'PyYAML', 'scipy'],
    extras_require={'sim': ['pybullet', 'matplotlib', 'mcap', 'rosbags']},
    zip_safe=True,
    maintainer='polyc2bf_ros maintainers',
    maintainer_email='maintainers@polyc2bf-ros.invalid',
    description='PolyC2BF control-barrier-function safety filter for ROS 2 Jazzy.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={'console_scripts': CONSOLE_SCRIPTS},
)

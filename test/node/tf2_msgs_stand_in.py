"""A stand-in ``tf2_msgs`` (TFMessage only) for tests, where the PyPI ROS wheels have none.

``tf2_msgs_python_path(root)`` returns the folder to put on ``sys.path`` / ``PYTHONPATH`` for
``from tf2_msgs.msg import TFMessage`` (None when a real tf2_msgs is installed).  The first
call builds it under ``root`` with the venv's own rosidl generators (the message, its C,
Fast DDS and introspection type supports, the Python bindings) and gcc: about 10 s.  The type
supports' libraries find each other by their absolute rpaths, and the dispatch library links
the Fast DDS one so that rmw finds it loaded: nothing needs ``LD_LIBRARY_PATH``.  Run as a
script (``python tf2_msgs_stand_in.py ROOT``) it only builds, with ``AMENT_PREFIX_PATH``
pointing at the venv for the generators' templates.
"""
import importlib.util
import os
import subprocess
import sys
import sysconfig
from pathlib import Path

PACKAGE = 'tf2_msgs'
DEFINITION = 'geometry_msgs/TransformStamped[] transforms\n'
BUILD_TIMEOUT_S = 600


def tf2_msgs_python_path(root):
    """Return the stand-in's Python folder under ``root`` (built on first use), or None."""
    if importlib.util.find_spec(PACKAGE) is not None:
        return None
    python = Path(root) / 'python'
    if not (python / PACKAGE / '__init__.py').exists():  # written last
        env = dict(os.environ, AMENT_PREFIX_PATH=sys.prefix)
        proc = subprocess.run([sys.executable, __file__, str(root)], env=env, text=True,
                              capture_output=True, timeout=BUILD_TIMEOUT_S)
        assert proc.returncode == 0, f'stand-in tf2_msgs build failed:\n{proc.stderr[-4000:]}'
    return str(python)


def _generate(root):
    """Write TFMessage.msg and run the generators; return their output folders."""
    from rosidl_generator_c.cli import GenerateC
    from rosidl_generator_py.cli import GeneratePython
    from rosidl_generator_type_description.cli import HashTypeDescription
    from rosidl_typesupport_c.cli import GenerateCTypesupport
    from rosidl_typesupport_fastrtps_c.cli import GenerateFastRTPSCTypesupport
    from rosidl_typesupport_introspection_c.cli import GenerateIntrospectionCTypesupport

    source = root / 'src' / 'msg'
    source.mkdir(parents=True, exist_ok=True)
    (source / 'TFMessage.msg').write_text(DEFINITION)
    files = [f'{root / "src"}:msg/TFMessage.msg']
    share = [Path(sys.prefix) / 'share']
    hashes = HashTypeDescription('type_description').generate_type_hashes(
        PACKAGE, files, share, root / 'hash')
    GenerateC('c').generate(PACKAGE, files, share, root / 'generator_c' / PACKAGE,
                            type_description_files=hashes)
    for name, generator in (('typesupport_c', GenerateCTypesupport),
                            ('typesupport_fastrtps_c', GenerateFastRTPSCTypesupport),
                            ('typesupport_introspection_c', GenerateIntrospectionCTypesupport)):
        generator(name).generate(PACKAGE, files, share, root / name / PACKAGE)
    python = root / 'python' / PACKAGE
    GeneratePython('py').generate(PACKAGE, files, share, python)
    return python


def _compile(root, python):
    """Compile the generated sources into the type support libraries and Python modules."""
    import numpy

    venv = Path(sys.prefix)
    lib = root / 'lib'
    lib.mkdir(exist_ok=True)
    includes = [venv / 'include', *sorted((venv / 'include').iterdir()),
                *(root / name for name in ('generator_c', 'typesupport_c',
                                           'typesupport_fastrtps_c',
                                           'typesupport_introspection_c')),
                numpy.get_include(), sysconfig.get_paths()['include']]
    flags = [f'-I{path}' for path in includes]

    def build(target, sources, libraries):
        cxx = any(str(s).endswith('.cpp') for s in sources)
        command = ['g++', '-std=c++17'] if cxx else ['gcc']
        command += ['-shared', '-fPIC', '-O1', *flags, *map(str, sources), '-o', str(target),
                    f'-L{venv / "lib"}', f'-L{lib}', f'-Wl,-rpath,{venv / "lib"}',
                    f'-Wl,-rpath,{lib}', f'-Wl,-soname,{target.name}', '-Wl,--no-as-needed',
                    *(f'-l{name}' for name in libraries)]
        subprocess.run(command, check=True)

    def sources(name, pattern):
        return sorted((root / name / PACKAGE).rglob(pattern))

    generator_c = f'{PACKAGE}__rosidl_generator_c'
    build(lib / f'lib{generator_c}.so', sources('generator_c', '*.c'),
          ['geometry_msgs__rosidl_generator_c', 'rosidl_runtime_c', 'rcutils'])
    build(lib / f'lib{PACKAGE}__rosidl_typesupport_introspection_c.so',
          sources('typesupport_introspection_c', '*.c'),
          [generator_c, 'geometry_msgs__rosidl_typesupport_introspection_c',
           'rosidl_typesupport_introspection_c', 'rosidl_runtime_c'])
    build(lib / f'lib{PACKAGE}__rosidl_typesupport_fastrtps_c.so',
          sources('typesupport_fastrtps_c', '*.cpp'),
          [generator_c, 'geometry_msgs__rosidl_typesupport_fastrtps_c',
           'rosidl_typesupport_fastrtps_c', 'rosidl_typesupport_fastrtps_cpp', 'fastcdr',
           'rmw', 'rosidl_runtime_c', 'rcutils'])
    build(lib / f'lib{PACKAGE}__rosidl_typesupport_c.so', sources('typesupport_c', '*.cpp'),
          [generator_c, f'{PACKAGE}__rosidl_typesupport_fastrtps_c',
           f'{PACKAGE}__rosidl_typesupport_introspection_c', 'rosidl_typesupport_c',
           'rosidl_runtime_c', 'rcpputils', 'rcutils'])
    generator_py = f'{PACKAGE}__rosidl_generator_py'
    build(lib / f'lib{generator_py}.so', sorted((python / 'msg').glob('*.c')),
          [generator_c, f'{PACKAGE}__rosidl_typesupport_c',
           'geometry_msgs__rosidl_generator_py', 'geometry_msgs__rosidl_generator_c',
           'rosidl_runtime_c'])
    suffix = sysconfig.get_config_var('EXT_SUFFIX')
    for entry in sorted(python.glob(f'_{PACKAGE}_s.ep.*.c')):
        typesupport = entry.name.removeprefix(f'_{PACKAGE}_s.ep.').removesuffix('.c')
        build(python / f'{PACKAGE}_s__{typesupport}{suffix}', [entry],
              [generator_py, f'{PACKAGE}__{typesupport}', generator_c, 'rosidl_runtime_c'])
    (python / '__init__.py').write_text('')


def main(root):
    """Build the stand-in under ``root``; the Python package is written last."""
    root = Path(root).resolve()
    _compile(root, _generate(root))
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1]))

"""Shared parts of the benchmarks: JSON records, and a check of what they measure.

Records are flat JSON lists (keys: doc/design.md, result records).  A benchmark started as
``.venv/bin/python bench/<name>.py`` imports the packages installed in the
virtualenv (Python puts the script's folder, not the repository, first on
``sys.path``), as do the console scripts it starts, while a node it starts with
``python -m`` from the repository root runs the checkout.  After an edit and
before ``make venv`` (which ``make bench`` runs) the installed copy is the
previous code, with the kernels built for it, so the numbers would be of other
code than the one they are reported for, or of a mix.
``require_installed_checkout`` refuses that.
"""
import filecmp
import importlib.util
import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ('polyc2bf_ros', 'sim_bridge')


def write_records(records, path):
    """Write ``records`` as an indented JSON list to ``path`` and say where."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(records, indent=1) + '\n')
    print(f'wrote {out}')


def differing_sources(source, installed):
    """Return the ``.py`` files under ``source`` missing or different under ``installed``.

    Paths are relative to ``source``, sorted.
    """
    source, installed = Path(source), Path(installed)
    differing = []
    for path in sorted(source.rglob('*.py')):
        relative = path.relative_to(source)
        copy = installed / relative
        if not (copy.is_file() and filecmp.cmp(path, copy, shallow=False)):
            differing.append(str(relative))
    return differing


def require_installed_checkout(repo=REPO, packages=PACKAGES):
    """Exit with the fix named when an imported package's sources differ from ``repo``'s."""
    stale = []
    for name in packages:
        spec = importlib.util.find_spec(name)
        if spec is None:
            sys.exit(f'{name} is not installed: run `make venv` first')
        installed = Path(next(iter(spec.submodule_search_locations)))
        stale += [f'{name}/{relative}'
                  for relative in differing_sources(Path(repo) / name, installed)]
    if stale:
        sys.exit(f'the installed packages differ from this checkout in {len(stale)} file(s) '
                 f'({", ".join(stale[:3])}{", ..." if len(stale) > 3 else ""}): run '
                 '`make venv` first (`make bench` does), so that the numbers are of this code')

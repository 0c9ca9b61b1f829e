"""Shared output of the benchmarks: flat JSON records (DESIGN.md section 8)."""
import json
from pathlib import Path


def write_records(records, path):
    """Write ``records`` as an indented JSON list to ``path`` and say where."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(records, indent=1) + '\n')
    print(f'wrote {out}')

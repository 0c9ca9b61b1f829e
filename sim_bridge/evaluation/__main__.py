"""``python -m sim_bridge.evaluation``: the ``evaluate`` command (``cli.main``)."""
import sys

from sim_bridge.evaluation.cli import main

sys.exit(main())

"""``python -m sins_align.montecarlo``: the montecarlo tool: simulated runs, error statistics, NEES
(:mod:`sins_align.tools.montecarlo`).

Kept at the package's top level so the documented command keeps working.
"""
import sys

from sins_align.tools.montecarlo import main

if __name__ == "__main__":
    sys.exit(main())

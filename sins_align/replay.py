"""``python -m sins_align.replay``: the replay tool: the estimator on recorded bags
(:mod:`sins_align.tools.replay`).

Kept at the package's top level so the documented command keeps working.
"""
import sys

from sins_align.tools.replay import main

if __name__ == "__main__":
    sys.exit(main())

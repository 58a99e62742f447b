"""``python -m sins_align.observability``: the observability tool: seed 001's piece-wise
constant system analysis of alignment with a velocity reference
(:mod:`sins_align.tools.observability`).

Kept at the package's top level so the documented command keeps working.
"""
import sys

from sins_align.tools.observability import main

if __name__ == "__main__":
    sys.exit(main())

"""``python -m sins_align.simulate``: the simulate tool: what imu_sim_node publishes, written to a
bag (:mod:`sins_align.tools.simulate`).

Kept at the package's top level so the documented command keeps working.
"""
import sys

from sins_align.tools.simulate import main

if __name__ == "__main__":
    sys.exit(main())

"""``python -m sins_align.align_node``: the align_node ROS 2 node
(:mod:`sins_align.ros.align_node`).

Kept at the package's top level so the documented command keeps working.
"""
import sys

from sins_align.ros.align_node import main

if __name__ == "__main__":
    sys.exit(main())

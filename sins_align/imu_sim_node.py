"""``python -m sins_align.imu_sim_node``: the imu_sim_node ROS 2 node
(:mod:`sins_align.ros.imu_sim_node`).

Kept at the package's top level so the documented command keeps working.
"""
import sys

from sins_align.ros.imu_sim_node import main

if __name__ == "__main__":
    sys.exit(main())

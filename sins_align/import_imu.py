"""``python -m sins_align.import_imu``: the import_imu tool: IMU logs to rosbag2
(:mod:`sins_align.tools.import_imu`).

Kept at the package's top level so the documented command keeps working.
"""
import sys

from sins_align.tools.import_imu import main

if __name__ == "__main__":
    sys.exit(main())

"""Input and output without ROS: rosbag2/ROS 1 bags (:mod:`~sins_align.io.bagio`, through
rosbags, with a fast MCAP chunk reader), CDR (:mod:`~sins_align.io.cdr`), the PSINS log
reader (:mod:`~sins_align.io.psins`) and the sensor_msgs/Imu field conventions
(:mod:`~sins_align.io.imu_fields`).
"""

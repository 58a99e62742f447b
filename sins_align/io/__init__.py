"""Input and output without ROS: rosbag2/ROS 1 bags (:mod:`~sins_align.io.bagio`, through
rosbags, with a fast MCAP chunk reader), CDR (:mod:`~sins_align.io.cdr`), the PSINS log
readers (:mod:`~sins_align.io.psins`: the text log and the transfer-alignment .mat), the
sensor_msgs/Imu field conventions (:mod:`~sins_align.io.imu_fields`) and the messages of a
master INS (:mod:`~sins_align.io.reference_msgs`).
"""

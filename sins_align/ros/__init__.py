"""The ROS 2 front: align_node, imu_sim_node, the demo, the one parameter schema
(:mod:`~sins_align.ros.params`) and the published outputs (:mod:`~sins_align.ros.outputs`,
shared with replay so node and replay publish the same thing).
"""

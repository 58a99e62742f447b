"""Command-line tools (each also ``python -m sins_align.<tool>`` and ``ros2 run sins_align
<tool>``): replay, simulate, import_imu, montecarlo.
"""

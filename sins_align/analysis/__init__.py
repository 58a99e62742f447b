"""Offline analyses of the alignment problem (numpy/scipy, no ROS)."""

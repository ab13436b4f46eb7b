"""Conversions between ROS 2 messages and the numpy arrays of the geomodel_ros core.

This is the only package that knows both worlds; it never calls ``rclpy.init``.
"""

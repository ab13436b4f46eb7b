"""Conversions between ROS 2 messages and the types of the geomodel_ros core.

Every module that reads or builds a message goes through these functions; they never call
``rclpy.init`` and import nothing of geomodel_ros but its core types.
"""

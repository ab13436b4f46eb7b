"""The message classes the ROS layer publishes and subscribes to.

Nodes and tools pass these to ``create_publisher`` / ``create_subscription``; building
and reading their fields is left to the other adapter modules.
"""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from visualization_msgs.msg import MarkerArray

__all__ = ["CameraInfo", "DiagnosticArray", "Image", "MarkerArray", "PointCloud2"]

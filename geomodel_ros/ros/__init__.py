"""The ROS 2 layer: the ``modeler`` node, its per-frame processing and rosbag2 tools."""

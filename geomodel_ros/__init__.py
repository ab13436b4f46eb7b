"""geomodel_ros: point clouds -> typed, sized geometric primitives.

Three layers, each a sub-package:

- :mod:`geomodel_ros.core` -- the method (segmentation, surface types, model graph, RANSAC
  fitting, sizing, reconstruction). numpy, scipy and open3d only; never imports ROS.
- :mod:`geomodel_ros.ros` -- the ROS 2 side: the ``modeler`` node, the per-frame processing
  it runs, rosbag2 tools. Messages are built and read only through :mod:`msg_adapters`.
- :mod:`geomodel_ros.tools` -- the ``geomodel`` command, benchmarks, evaluation, rendering,
  the demo, synthetic scenes and point-cloud files.
"""

__version__ = "0.1.0"

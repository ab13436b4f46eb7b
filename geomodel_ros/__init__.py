"""geomodel_ros: point clouds -> typed, sized geometric primitives.

The core (everything in this package except :mod:`geomodel_ros.node`) depends on
numpy, scipy and open3d only; ROS message handling lives in :mod:`msg_adapters`.
"""

__version__ = "0.1.0"

"""Launch the ``modeler`` node with its parameters file, topic remaps and optionally RViz.

Usage::

    ros2 launch geomodel_ros modeler.launch.py points_topic:=/camera/depth/points rviz:=true
    ros2 launch geomodel_ros modeler.launch.py input:=depth \
        depth_image_topic:=/camera/depth/image_rect_raw \
        camera_info_topic:=/camera/depth/camera_info
    ros2 launch geomodel_ros modeler.launch.py namespace:=cam2 \
        points_topic:=/cam2/depth/points params_file:=/path/to/kinect.yaml

The launch arguments:

* ``params_file``: the node's parameters (default: the installed ``config/modeler.yaml``;
  ``config/kinect.yaml`` and ``config/sensor_noise.yaml`` are installed beside it).
* ``namespace``: namespace of the node, for a second camera (outputs then live under
  ``/<namespace>/modeler/...``; the RViz config shows the un-namespaced ``/modeler/...``).
* ``input``: ``points`` (PointCloud2, default) or ``depth`` (depth image + CameraInfo:
  4-8x smaller messages, delivered between processes with the middleware's defaults).
* ``points_topic``: the PointCloud2 to model (remap of the node's ``points`` input).
* ``depth_image_topic``, ``camera_info_topic``: the depth image (16UC1 mm or 32FC1 m,
  rectified/registered) and its CameraInfo (remaps of ``depth/image_raw`` and
  ``depth/camera_info``), used with ``input:=depth``.
* ``qos_reliability``: ``auto`` (default: reliable when every publisher is reliable, else
  best effort), ``best_effort`` or ``reliable``.
* ``sensor_frame``: the sensor's optical frame, for clouds published in another frame (the
  node looks its pose up with tf2 for every frame; needed for unorganized clouds in a
  robot's frame); empty by default.
* ``workers``: frames modeled at once, each in its own worker process (default 1: in the
  node's process); on a computer with several cores, up to about one per core raises the
  processed rate.
* ``use_large_data_profile``: ``true`` sets ``FASTRTPS_DEFAULT_PROFILES_FILE`` to the
  installed ``config/fastdds_large_data.xml`` (shared memory only, 64 MiB segments) for
  every process this file starts (the node and RViz); it carries clouds of several MB even
  from a best-effort publisher.  A driver started elsewhere needs the same variable (the
  README gives the command lines); off by default because a process with the profile
  talks only to processes on this host.
* ``rviz``: ``true`` also starts ``rviz2`` with the installed ``config/modeler.rviz``.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

PACKAGE = "geomodel_ros"


def generate_launch_description():
    """Return the launch description of the modeler (and optionally RViz)."""
    share = get_package_share_directory(PACKAGE)
    config = os.path.join(share, "config")
    params_file = LaunchConfiguration("params_file")
    namespace = LaunchConfiguration("namespace")
    points_topic = LaunchConfiguration("points_topic")
    input_kind = LaunchConfiguration("input")
    depth_image_topic = LaunchConfiguration("depth_image_topic")
    camera_info_topic = LaunchConfiguration("camera_info_topic")
    qos_reliability = LaunchConfiguration("qos_reliability")
    workers = LaunchConfiguration("workers")
    sensor_frame = LaunchConfiguration("sensor_frame")
    use_large_data_profile = LaunchConfiguration("use_large_data_profile")
    rviz = LaunchConfiguration("rviz")

    return LaunchDescription([
        DeclareLaunchArgument(
            "params_file", default_value=os.path.join(config, "modeler.yaml"),
            description="YAML file with the node's parameters (key: modeler)."),
        DeclareLaunchArgument(
            "namespace", default_value="",
            description="Namespace of the node (e.g. one per camera)."),
        DeclareLaunchArgument(
            "points_topic", default_value="/camera/depth/points",
            description="sensor_msgs/PointCloud2 input, remapped onto the node's 'points'."),
        DeclareLaunchArgument(
            "input", default_value="points",
            description="What to model: points (PointCloud2) or depth (image + CameraInfo)."),
        DeclareLaunchArgument(
            "depth_image_topic", default_value="/camera/depth/image_rect_raw",
            description="sensor_msgs/Image depth input (input:=depth), 16UC1 or 32FC1."),
        DeclareLaunchArgument(
            "camera_info_topic", default_value="/camera/depth/camera_info",
            description="sensor_msgs/CameraInfo of the depth image (input:=depth)."),
        DeclareLaunchArgument(
            "qos_reliability", default_value="auto",
            description="Input reliability: auto (follow the publishers), best_effort or "
                        "reliable."),
        DeclareLaunchArgument(
            "sensor_frame", default_value="",
            description="The sensor's optical frame, for clouds in another frame (tf2)."),
        DeclareLaunchArgument(
            "workers", default_value="1",
            description="Frames modeled at once, each in its own worker process."),
        DeclareLaunchArgument(
            "use_large_data_profile", default_value="false",
            description="Use config/fastdds_large_data.xml (shared memory, large clouds)."),
        DeclareLaunchArgument(
            "rviz", default_value="false",
            description="Also start rviz2 with config/modeler.rviz."),
        SetEnvironmentVariable(
            "FASTRTPS_DEFAULT_PROFILES_FILE",
            os.path.join(config, "fastdds_large_data.xml"),
            condition=IfCondition(use_large_data_profile)),
        Node(
            package=PACKAGE,
            executable="modeler",
            name="modeler",
            namespace=namespace,
            # An empty string read as YAML is no value: the frame is typed as a string.
            parameters=[params_file, {"qos_reliability": qos_reliability,
                                      "input": input_kind, "workers": workers,
                                      "sensor_frame": ParameterValue(sensor_frame,
                                                                     value_type=str)}],
            remappings=[("points", points_topic), ("depth/image_raw", depth_image_topic),
                        ("depth/camera_info", camera_info_topic)],
            output="screen",
        ),
        Node(
            package="rviz2",
            executable="rviz2",
            name="rviz2",
            arguments=["-d", os.path.join(config, "modeler.rviz")],
            condition=IfCondition(rviz),
            output="screen",
        ),
    ])

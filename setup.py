"""ament_python package definition for geomodel_ros."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "geomodel_ros"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*", "msg_adapters", "msg_adapters.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config",
         glob("config/*.yaml") + glob("config/*.xml") + glob("config/*.rviz")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="geomodel_ros maintainers",
    maintainer_email="maintainers@geomodel-ros.dev",
    description="Point cloud -> typed, sized geometric primitives for ROS 2 Jazzy.",
    license="BSD-3-Clause",
    entry_points={
        "console_scripts": [
            "geomodel = geomodel_ros.tools.cli:main",
            "modeler = geomodel_ros.ros.node:main",
        ],
    },
)

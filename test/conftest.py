"""Test-session configuration.

DDS must stay on loopback and parallel runs must not see each other: both variables are
set here, before any test module can import rclpy.
"""

import os

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
# One domain per test session (0-101 are valid with the default port mapping).
os.environ.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))

import pytest  # noqa: E402


@pytest.fixture
def context():
    """Give one test a private, initialized rclpy Context (shut down afterwards)."""
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(args=[], context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)

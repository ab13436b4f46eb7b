"""The ROS-free core: scene segmentation and geometric modeling (numpy, scipy, open3d, pykdtree)."""

"""Support planes: a plane is a support only if its large connected pieces add up.

Hand-made clouds on one plane z = 0.8 m facing the camera at the origin; areas follow from
the patch sizes alone (the defaults: ``seg_min_support_area`` 0.1 m^2; pieces smaller than
10 % of it do not count towards a support, see core/support.py).
"""

from __future__ import annotations

import numpy as np

from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.segmentation import segment_scene

Z = 0.8
SPACING = 0.002  # sample spacing [m], finer than the 4 mm segmentation voxel


def patch(x0: float, y0: float, side: float) -> np.ndarray:
    """Points of a square patch of the plane z = Z with its corner at (x0, y0) [m]."""
    g = np.arange(0.0, side, SPACING)
    u, v = np.meshgrid(g, g)
    return np.column_stack([x0 + u.ravel(), y0 + v.ravel(), np.full(u.size, Z)])


def test_one_large_plane_is_a_support():
    area = 0.4 * 0.4
    assert area > ModelingParams().seg_min_support_area
    seg = segment_scene(patch(-0.2, -0.2, 0.4))
    assert len(seg.support_planes) == 1
    (normal, d), = seg.support_planes.values()
    assert abs(abs(normal[2]) - 1.0) < 1e-6 and abs(abs(d) - Z) < 1e-6


def test_coplanar_pieces_too_small_to_count_are_no_support():
    # Two 12 cm squares (0.0144 m^2 each: large pieces, together 0.029 m^2) and 64 scattered
    # 4 cm squares (0.0016 m^2 each, 2 cm apart: small pieces, together 0.10 m^2). All lie on
    # one plane holding 0.13 m^2 > 0.1 m^2, but its large pieces hold only 0.029 m^2.
    params = ModelingParams()
    large = [patch(-0.40, -0.30, 0.12), patch(-0.40, 0.10, 0.12)]
    small = [patch(-0.10 + 0.06 * i, -0.30 + 0.06 * j, 0.04) for i in range(8) for j in range(8)]
    assert 2 * 0.12 ** 2 < params.seg_min_support_area < 2 * 0.12 ** 2 + 64 * 0.04 ** 2
    seg = segment_scene(np.vstack(large + small), params)
    assert seg.support_planes == {}

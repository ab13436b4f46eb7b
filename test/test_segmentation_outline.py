"""A patch border seen as one patch's outline in front of the other.

Hand-made scenes, the geometry worked out in the comments. Working points on a square grid
4 mm apart (the default ``seg_voxel_size``), the sensor at the origin looking along +z;
links reach ``max_edge`` = 2.5 spacings = 10 mm.

- Two halves of one plane at 0.8 m (split along x = 0 as two patches): every pair of image
  neighbours across the seam is about 4-6 mm apart in 3-D, within a link: no outline.
- A vertical board (the near patch, a box's front face at z = 0.8 m) in front of a plane
  behind it (z = 0.8 m + gap), both facing the sensor, the board's right edge touching the
  back plane only in its lower part: the back plane bends forward and meets the board
  along a short strip. Across the board's outline the image neighbours on the back plane
  lie ``gap`` deeper, beyond a link where the gap exceeds 10 mm: most of the seam is
  jumps and the border is an outline, whatever the votes of the few links at the contact.
- The same with a gap of 6 mm (a step shorter than a link): no outline.
- A container's inner wall behind its rim is an outline too; it is told by its median
  in-patch fold, negative on a surface seen from inside (concave), and left to the votes.
"""

from __future__ import annotations

import numpy as np

from geomodel_ros.core.segmentation import _concave_patches, _occluding_borders

MM = 1e-3
SPACING = 4 * MM
MAX_EDGE = 2.5 * SPACING
Z = 0.8


def _grid(x0, x1, y0, y1, z, spacing=SPACING):
    """Points of the plane z = ``z`` [m] on a square grid over [x0, x1) x [y0, y1)."""
    xs = np.arange(x0, x1, spacing)
    ys = np.arange(y0, y1, spacing)
    x, y = np.meshgrid(xs, ys)
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])


def _facing(pts):
    """Return the normals of planes z = const towards the sensor at the origin: -z."""
    return np.tile([0.0, 0.0, -1.0], (len(pts), 1))


def _pairs():
    """Return the one border (a < b) of two patches 0 and 1."""
    return np.array([0]), np.array([1])


def test_two_halves_of_one_plane_are_no_outline():
    left = _grid(-0.05, 0.0, -0.05, 0.05, Z)
    right = _grid(0.0, 0.05, -0.05, 0.05, Z)
    pts = np.vstack([left, right])
    patches = np.repeat([0, 1], [len(left), len(right)])
    a, b = _pairs()
    assert not _occluding_borders(pts, _facing(pts), patches, a, b, 2, SPACING, MAX_EDGE)[0]


def _board_in_front(gap, contact_rows=3):
    """Return a board x < 0 at z = Z before a plane at z = Z + gap, and the two patches.

    Seen from the sensor, the back plane's part behind the board is hidden: only its points
    right of the board's image outline remain. Along the lowest ``contact_rows`` rows the
    back plane is brought forward to the board's depth (the contact, a few links long).
    """
    board = _grid(-0.05, 0.0, -0.05, 0.05, Z)
    # The back plane's visible points continue the board's image columns: the next column
    # of rays after the board's last one (x / z = -2.5 mm / 0.8 m + one spacing / Z), at
    # the back plane's depth (so 4 (Z + gap) / Z mm apart in 3-D).
    last = board[:, 0].max() / Z
    cols = last + SPACING / Z * np.arange(1, 16)
    rows = board[board[:, 0] == board[:, 0].max(), 1] / Z
    u, v = np.meshgrid(cols, rows)
    back = np.column_stack([u.ravel(), v.ravel(), np.ones(u.size)]) * (Z + gap)
    low = back[:, 1] < back[:, 1].min() + (contact_rows - 0.5) * SPACING
    back[low, :] *= Z / (Z + gap)  # the same rays, now at the board's depth
    pts = np.vstack([board, back])
    patches = np.repeat([0, 1], [len(board), len(back)])
    return pts, patches


def test_board_in_front_of_a_plane_is_an_outline():
    # A gap of 30 mm: the image neighbours across the outline are 30 mm apart along the
    # ray, three links; only the three contact rows (of 25 rows of seam) meet in 3-D.
    pts, patches = _board_in_front(30 * MM)
    a, b = _pairs()
    assert _occluding_borders(pts, _facing(pts), patches, a, b, 2, SPACING, MAX_EDGE)[0]


def test_a_step_shorter_than_a_link_is_no_outline():
    # A gap of 6 mm: across the outline the neighbours are within 4-8 mm, within a link.
    pts, patches = _board_in_front(6 * MM)
    a, b = _pairs()
    assert not _occluding_borders(pts, _facing(pts), patches, a, b, 2, SPACING, MAX_EDGE)[0]


def test_mostly_contact_is_no_outline():
    # Contact along 15 of the 25 rows: the jumps are a minority of the seam.
    pts, patches = _board_in_front(30 * MM, contact_rows=15)
    a, b = _pairs()
    assert not _occluding_borders(pts, _facing(pts), patches, a, b, 2, SPACING, MAX_EDGE)[0]


def _cylinder_patch(radius, inside, z_axis=Z, half_angle=0.6, height=0.06):
    """Working points of a vertical cylinder's side (axis along y through (0, ., z_axis)).

    ``inside``: the half facing away from the sensor, seen from inside (a container's inner
    back wall through its opening: concave); otherwise the half facing the sensor (convex).
    Normals point towards the sensor. Points 4 mm apart along the arc and the axis.
    """
    n_arc = int(2 * half_angle * radius / SPACING)
    phi = np.linspace(-half_angle, half_angle, n_arc)
    ys = np.arange(-height / 2, height / 2, SPACING)
    phi, y = np.meshgrid(phi, ys)
    phi, y = phi.ravel(), y.ravel()
    side = 1.0 if inside else -1.0  # +: the far half (z > z_axis), -: the near half
    pts = np.column_stack([radius * np.sin(phi), y, z_axis + side * radius * np.cos(phi)])
    outward = np.column_stack([np.sin(phi), np.zeros_like(phi), side * np.cos(phi)])
    normals = -outward if inside else outward  # towards the sensor either way
    return pts, normals


def _patch_links(pts, k=16):
    """Nearest neighbours (itself included) and their squared distances."""
    from scipy.spatial import cKDTree
    d, nb = cKDTree(pts).query(pts, k=k)
    return nb, d * d


def test_a_wall_seen_from_inside_is_concave_and_from_outside_not():
    # Radius 40 mm: a link of length l folds by l^2 / (2 r), 0.2-1.25 mm over 4-10 mm links;
    # negative seen from inside (the surface bends towards the sensor), positive outside.
    for inside in (True, False):
        pts, normals = _cylinder_patch(0.04, inside)
        nb, sq = _patch_links(pts)
        patches = np.zeros(len(pts), dtype=np.int64)
        got = _concave_patches(pts, normals, nb, sq, patches, 1, MAX_EDGE)
        assert got[0] == inside


def test_a_plane_is_not_concave():
    pts = _grid(-0.05, 0.05, -0.05, 0.05, Z)
    nb, sq = _patch_links(pts)
    got = _concave_patches(pts, _facing(pts), nb, sq, np.zeros(len(pts), dtype=np.int64), 1,
                           MAX_EDGE)
    assert not got[0]


def test_an_outline_over_a_concave_patch_is_left_to_the_votes():
    # The board in front of the plane behind, as above (an outline), but the patch behind
    # (patch 1) is concave: a container's inner wall behind its own rim.
    pts, patches = _board_in_front(30 * MM)
    a, b = _pairs()
    normals = _facing(pts)
    assert _occluding_borders(pts, normals, patches, a, b, 2, SPACING, MAX_EDGE,
                              concave=lambda _: np.array([False, False]))[0]
    assert not _occluding_borders(pts, normals, patches, a, b, 2, SPACING, MAX_EDGE,
                                  concave=lambda _: np.array([False, True]))[0]
    # The front patch's own shape does not matter: the patch behind is the farther one.
    assert _occluding_borders(pts, normals, patches, a, b, 2, SPACING, MAX_EDGE,
                              concave=lambda _: np.array([True, False]))[0]


def test_terraces_one_depth_step_apart_are_no_outline():
    # A board 15 mm in front of the plane behind (a jump beyond a 10 mm link), but every
    # working point holds one disparity level of a 15 mm depth step (a Kinect at about
    # 2.4 m): the two are a step apart, within a link plus the two ends' quanta.
    pts, patches = _board_in_front(15 * MM, contact_rows=0)
    a, b = _pairs()
    normals = _facing(pts)
    assert _occluding_borders(pts, normals, patches, a, b, 2, SPACING, MAX_EDGE)[0]
    quantum = np.full(len(pts), 15 * MM)
    assert not _occluding_borders(pts, normals, patches, a, b, 2, SPACING, MAX_EDGE,
                                  quantum=quantum)[0]


def test_a_jump_within_the_noise_of_a_difference_is_no_outline():
    # A 15 mm gap is beyond a 10 mm link, but with 4 mm of noise at each end (a far
    # stereo depth) the gap's noise is 4 sqrt(2) = 5.7 mm and the limit 15.7 mm.
    pts, patches = _board_in_front(15 * MM, contact_rows=0)
    a, b = _pairs()
    noise = np.full(len(pts), 4 * MM)
    assert not _occluding_borders(pts, _facing(pts), patches, a, b, 2, SPACING, MAX_EDGE,
                                  noise=noise)[0]
    assert _occluding_borders(pts, _facing(pts), patches, a, b, 2, SPACING, MAX_EDGE,
                              noise=noise / 2)[0]


def test_only_the_patches_asked_for_are_judged():
    # Two concave walls; asked about the second only, the first is not judged (not concave).
    pts, normals = _cylinder_patch(0.04, True)
    nb, sq = _patch_links(pts)
    patches = (pts[:, 0] > 0).astype(np.int64)
    assert list(_concave_patches(pts, normals, nb, sq, patches, 2, MAX_EDGE)) == [True, True]
    assert list(_concave_patches(pts, normals, nb, sq, patches, 2, MAX_EDGE,
                                 np.array([1]))) == [False, True]

"""Tests of the synthetic depth-camera simulator and the paper's desk scenes."""

from __future__ import annotations

import json
import tracemalloc

import numpy as np
import pytest
from scipy.spatial import cKDTree

from geomodel_ros.tools.synth import (
    PAPER_SCENE_NAMES,
    SCENE_NAMES,
    SENSOR_NOISE,
    Box,
    Cone,
    Cylinder,
    GroundTruthObject,
    NoiseModel,
    PinholeCamera,
    Rectangle,
    Sphere,
    Torus,
    render_scene,
    scene_geometry,
)

SMALL_CAMERA = PinholeCamera(fx=150.0, fy=150.0, cx=59.5, cy=44.5, width=120, height=90)


def random_rotation(rng) -> np.ndarray:
    """Uniform random proper rotation (columns = axes)."""
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1.0
    return q


def make_shape(kind: str, rng):
    """One shape of each kind, randomly rotated, about 0.5 m in front of the camera."""
    pose = {"center": np.array([0.01, -0.02, 0.5]), "rotation": random_rotation(rng)}
    return {
        "rectangle": lambda: Rectangle(0.2, 0.12, **pose),
        "box": lambda: Box(0.12, 0.08, 0.05, **pose),
        "cylinder": lambda: Cylinder(0.04, 0.12, **pose),
        "cone": lambda: Cone(0.05, 0.1, **pose),
        "sphere": lambda: Sphere(0.06, **pose),
        "torus": lambda: Torus(0.06, 0.02, **pose),
    }[kind]()


def implicit_boundary(shape, points: np.ndarray) -> np.ndarray:
    """Return an independent implicit function of each surface.

    Zero on the surface and (up to a bounded factor) a distance: written here from the
    shape's definition, not taken from the shapes module.
    """
    p = (points - shape.center) @ shape.rotation
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    rho = np.hypot(x, y)
    if isinstance(shape, Rectangle):
        assert np.all(np.abs(x) <= shape.length / 2 + 1e-12)
        assert np.all(np.abs(y) <= shape.width / 2 + 1e-12)
        return z
    if isinstance(shape, Box):
        h = np.array([shape.length, shape.width, shape.height]) / 2
        return (np.abs(p) - h).max(axis=1)
    if isinstance(shape, Cylinder):
        return np.maximum(rho - shape.radius, np.abs(z) - shape.height / 2)
    if isinstance(shape, Cone):
        k = shape.radius / shape.height
        lateral = (rho - k * (shape.height / 2 - z)) / np.sqrt(1 + k * k)
        return np.maximum(lateral, -shape.height / 2 - z)
    if isinstance(shape, Sphere):
        return np.linalg.norm(p, axis=1) - shape.radius
    if isinstance(shape, Torus):
        return np.hypot(rho - shape.major_radius, z) - shape.minor_radius
    raise AssertionError(type(shape))


KINDS = ("rectangle", "box", "cylinder", "cone", "sphere", "torus")


# --------------------------------------------------------------------------- shapes
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("seed", [0, 1])
def test_hits_lie_on_the_surface(kind, seed):
    shape = make_shape(kind, np.random.default_rng(seed))
    organized, labels = SMALL_CAMERA.render([shape], ids=[3])
    hit = labels == 3
    assert hit.sum() > 50  # a random pose may show the rectangle almost edge-on
    assert np.array_equal(hit, np.isfinite(organized).all(axis=2))
    assert set(np.unique(labels)) <= {-1, 3}
    pts = organized[hit]
    assert np.abs(implicit_boundary(shape, pts)).max() < 1e-9
    assert shape.surface_distance(pts).max() < 1e-9


@pytest.mark.parametrize("kind", [k for k in KINDS if k != "rectangle"])
def test_intersection_is_nearest_and_misses_are_misses(kind):
    """Check by ray marching: no sample before the reported hit lies inside the solid.

    Nor any sample of a missing ray.
    """
    shape = make_shape(kind, np.random.default_rng(7))
    d = SMALL_CAMERA.ray_directions()
    t = shape.intersect(np.zeros(3), d)
    assert t.shape == (d.shape[0],)
    near = np.linalg.norm(shape.center) - shape.bounding_radius
    far = np.linalg.norm(shape.center) + shape.bounding_radius
    s = np.linspace(near, far, 400)
    samples = d[:, None, :] * s[None, :, None]
    sdf = shape.signed_distance(samples.reshape(-1, 3)).reshape(len(d), len(s))
    before = s[None, :] < np.where(np.isfinite(t), t, np.inf)[:, None] - 1e-9
    assert np.all(sdf[before] > -1e-9)
    # every hitting ray enters the solid (or grazes it) right after the hit
    hit = np.isfinite(t)
    assert hit.sum() > 300
    p_after = d[hit] * (t[hit] + 1e-5)[:, None]
    assert np.mean(shape.signed_distance(p_after) < 0) > 0.99


#: Rotation that turns a shape's local z (cylinder/cone axis) onto the camera's y axis.
Z_TO_Y = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
#: Rotation that points a shape's local z back at the camera (-z).
Z_TO_MINUS_Z = np.diag([1.0, -1.0, -1.0])

# Rays along +z from (x0, 0, 0) at shapes centred 0.5 m ahead, (x0 [m], near t [m], far t [m])
# worked out by hand; the far hit is the back side that a ray must never report.
NEAR_HITS = [
    # upright cylinder r = 50 mm: (0.03, z) on the circle x^2 + (z - 0.5)^2 = 0.05^2 at
    # z = 0.5 -+ 0.04 (3-4-5 triangle)
    ("cylinder side", lambda: Cylinder(0.05, 0.2, center=[0, 0, 0.5], rotation=Z_TO_Y),
     0.03, 0.46, 0.54),
    ("cylinder side, on the axis", lambda: Cylinder(0.05, 0.2, center=[0, 0, 0.5],
                                                     rotation=Z_TO_Y), 0.0, 0.45, 0.55),
    # cylinder along the optical axis, height 100 mm: near cap at 0.45, far cap at 0.55
    ("cylinder cap", lambda: Cylinder(0.05, 0.1, center=[0, 0, 0.5]), 0.02, 0.45, 0.55),
    # sphere r = 50 mm: same circle as the cylinder side
    ("sphere", lambda: Sphere(0.05, center=[0, 0, 0.5]), 0.03, 0.46, 0.54),
    # cone r = 50 mm, h = 100 mm, apex towards the camera at z = 0.45: the radius grows by
    # 0.5 mm per mm from the apex, so x0 = 25 mm meets the side at z = 0.50; the base cap is
    # at z = 0.55
    ("cone apex first", lambda: Cone(0.05, 0.1, center=[0, 0, 0.5], rotation=Z_TO_MINUS_Z),
     0.025, 0.50, 0.55),
    # the same cone turned round: base cap first at z = 0.45, then the side at z = 0.50
    ("cone base first", lambda: Cone(0.05, 0.1, center=[0, 0, 0.5]), 0.025, 0.45, 0.50),
    ("box", lambda: Box(0.1, 0.1, 0.1, center=[0, 0, 0.5]), 0.03, 0.45, 0.55),
]


@pytest.mark.parametrize("what, build, x0, near, far", NEAR_HITS,
                         ids=[h[0] for h in NEAR_HITS])
def test_a_ray_reports_the_near_hit_not_the_back_side(what, build, x0, near, far):
    shape = build()
    t = shape.intersect(np.array([[x0, 0.0, 0.0]]), np.array([[0.0, 0.0, 1.0]]))
    assert abs(t[0] - near) < 1e-12, (what, t[0], far)
    # from inside the solid (past the near hit) the same ray leaves through the back side
    t_in = shape.intersect(np.array([[x0, 0.0, 0.5 * (near + far)]]),
                           np.array([[0.0, 0.0, 1.0]]))
    assert abs(t_in[0] - 0.5 * (far - near)) < 1e-12


@pytest.mark.parametrize("what, build", [h[:2] for h in NEAR_HITS],
                         ids=[h[0] for h in NEAR_HITS])
def test_the_camera_sees_the_near_hit(what, build):
    """Check that the centre pixel (the optical axis) sees z = 0.45, never 0.55.

    Every shape of NEAR_HITS is met there first at z = 0.45 (near cap, face, apex or the
    circle's nearest point).
    """
    cam = PinholeCamera(fx=100.0, fy=100.0, cx=10.0, cy=10.0, width=21, height=21)
    organized, labels = cam.render([build()], ids=[4])
    assert labels[10, 10] == 4, what
    np.testing.assert_allclose(organized[10, 10], [0.0, 0.0, 0.45], rtol=0, atol=1e-12)


@pytest.mark.parametrize("kind", KINDS)
def test_rendered_points_face_the_camera(kind):
    """Check that every hit is where its ray enters the solid.

    The outward normal (gradient of the independent implicit function) points back
    towards the camera.
    """
    shape = make_shape(kind, np.random.default_rng(3))
    organized, labels = SMALL_CAMERA.render([shape])
    p = organized[labels == 0]
    assert len(p) > 50
    h = 1e-7
    grad = np.stack([(implicit_boundary(shape, p + h * e) - implicit_boundary(shape, p - h * e))
                     / (2 * h) for e in np.eye(3)], axis=1)
    if kind == "rectangle":  # no inside: either side faces the camera
        grad *= -np.sign(np.einsum("ij,ij->i", grad, p))[:, None]
    view = p / np.linalg.norm(p, axis=1, keepdims=True)
    cos = np.einsum("ij,ij->i", grad, view) / np.linalg.norm(grad, axis=1)
    assert np.all(cos <= 1e-6), cos.max()
    assert np.median(cos) < -0.3
    # and it lies on the surface of that shape
    assert np.abs(implicit_boundary(shape, p)).max() < 1e-9


def test_a_posed_camera_projects_through_its_pose_and_refuses_to_ray_cast():
    # camera 1 m behind the scene origin, turned 90 deg about y: scene +x is its forward z
    rot = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    cam = PinholeCamera(100.0, 100.0, 10.0, 10.0, 21, 21, rot, np.array([0.0, 0.0, 1.0]))
    # scene point (1, 0.1, 0): camera frame (0, 0.1, 2) -> pixel (10, 10 + 100 * 0.1 / 2)
    np.testing.assert_allclose(cam.project([[1.0, 0.1, 0.0]]), [[10.0, 15.0]], atol=1e-12)
    assert np.isnan(cam.project([[-3.0, 0.0, 0.0]])).all()  # behind it
    assert cam.scaled(2.0).rotation.tolist() == rot.tolist()
    assert cam != PinholeCamera(100.0, 100.0, 10.0, 10.0, 21, 21)
    assert cam == PinholeCamera(100.0, 100.0, 10.0, 10.0, 21, 21, rot, [0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="identity pose"):
        cam.render([Sphere(0.1, center=[1.0, 0.0, 0.0])])


def test_intersect_accepts_unnormalised_directions_and_origins():
    sphere = Sphere(0.1, center=[0.0, 0.0, 1.0])
    origins = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 2.0]])
    directions = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, -1.0]])
    np.testing.assert_allclose(sphere.intersect(origins, directions), [0.45, 0.9])
    assert np.isinf(sphere.intersect(np.zeros(3), np.array([[1.0, 0.0, 0.0]]))[0])


def test_rectangle_is_hit_from_both_sides():
    front = Rectangle(0.2, 0.2, center=[0, 0, 0.5])
    back = Rectangle(0.2, 0.2, center=[0, 0, 0.5], rotation=np.diag([1.0, -1.0, -1.0]))
    for r in (front, back):
        _, labels = SMALL_CAMERA.render([r])
        assert (labels == 0).sum() > 1000
    assert front.ground_truth(0).rotation[2, 2] == -1.0  # normal faces the camera
    assert back.ground_truth(0).rotation[2, 2] == -1.0


def test_torus_hole_shows_the_background():
    torus = Torus(0.06, 0.02, center=[0, 0, 0.5])  # axis = optical axis
    wall = Rectangle(0.5, 0.5, center=[0, 0, 0.7])
    organized, labels = SMALL_CAMERA.render([wall, torus])
    centre_pixel = labels[44:46, 59:61]
    assert np.all(centre_pixel == 0)
    ring_pixel = SMALL_CAMERA.project(np.array([[0.06, 0.0, 0.48]])).round().astype(int)[0]
    assert labels[ring_pixel[1], ring_pixel[0]] == 1


# --------------------------------------------------------------------------- occlusion
def test_box_in_front_of_plane_hides_it():
    wall = Rectangle(1.0, 1.0, center=[0.0, 0.0, 0.8])
    box = Box(0.1, 0.08, 0.06, center=[0.02, 0.0, 0.5],
              rotation=random_rotation(np.random.default_rng(3)))
    _, box_alone = SMALL_CAMERA.render([box])
    organized, labels = SMALL_CAMERA.render([wall, box])
    silhouette = box_alone == 0
    assert silhouette.sum() > 300
    assert np.all(labels[silhouette] == 1)  # no plane behind the box
    assert np.all(labels[~silhouette] == 0)  # plane everywhere else
    # depth of the composite = minimum of the individual depths
    z_wall = SMALL_CAMERA.render([wall])[0][..., 2]
    z_box = SMALL_CAMERA.render([box])[0][..., 2]
    np.testing.assert_allclose(organized[..., 2], np.fmin(z_wall, z_box), rtol=0, atol=1e-12)


def test_sphere_shows_only_its_camera_facing_hemisphere():
    sphere = Sphere(0.08, center=[0.03, -0.02, 0.6])
    organized, labels = SMALL_CAMERA.render([sphere])
    p = organized[labels == 0]
    outward = (p - sphere.center) / sphere.radius
    view = p / np.linalg.norm(p, axis=1, keepdims=True)
    assert np.all(np.einsum("ij,ij->i", outward, view) <= 1e-9)
    # nearest point of the sphere seen, back side never
    assert np.linalg.norm(p, axis=1).max() <= np.linalg.norm(sphere.center)


def test_camera_geometry_round_trip():
    scene = render_scene("tiny_box")
    cam = PinholeCamera(**scene.intrinsics)
    v, u = np.nonzero(scene.valid_mask)  # row-major order
    uv = cam.project(scene.points)
    np.testing.assert_allclose(uv, np.stack([u, v], axis=1), atol=1e-9)
    assert scene.labels.dtype == np.int32 and scene.labels.shape == (len(scene.points),)


def test_memory_of_a_large_render_is_bounded():
    cam = PinholeCamera(fx=1000.0, fy=1000.0, cx=399.5, cy=349.5, width=800, height=700)
    rng = np.random.default_rng(0)
    shapes = [Rectangle(1.0, 1.0, center=[0, 0, 0.9])]
    builders = (
        lambda c, r: Box(0.05, 0.04, 0.03, center=c, rotation=r),
        lambda c, r: Cylinder(0.03, 0.05, center=c, rotation=r),
        lambda c, r: Cone(0.03, 0.05, center=c, rotation=r),
        lambda c, r: Sphere(0.03, center=c, rotation=r),
        lambda c, r: Torus(0.04, 0.012, center=c, rotation=r),
    )
    for i in range(11):
        center = [rng.uniform(-0.15, 0.15), rng.uniform(-0.15, 0.15), 0.5 + 0.02 * i]
        shapes.append(builders[i % 5](center, random_rotation(rng)))
    tracemalloc.start()
    try:
        organized, labels = cam.render(shapes)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert organized.shape == (700, 800, 3) and labels.shape == (700, 800)
    assert len(np.unique(labels)) > 6
    assert peak < 500e6


# --------------------------------------------------------------------------- scenes
@pytest.fixture(scope="module")
def paper_scenes():
    return {name: render_scene(name) for name in PAPER_SCENE_NAMES}


@pytest.mark.parametrize("name", PAPER_SCENE_NAMES)
def test_paper_scene_statistics(paper_scenes, name):
    scene = paper_scenes[name]
    assert 355_000 <= len(scene.points) <= 380_000
    assert scene.organized.dtype == np.float64 and scene.label_image.dtype == np.int32
    counts = np.bincount(scene.labels, minlength=len(scene.objects))
    assert len(counts) == len(scene.objects)
    assert counts.min() >= 500, counts
    # nothing of any object touches the image border: everything is in view
    lab = scene.label_image
    border = np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]])
    assert np.all(border == -1)
    # point spacing on the desk ~0.5 mm (tree on all desk points, subsampled queries)
    desk = scene.points[scene.labels == 0]
    idx = np.random.default_rng(0).choice(len(desk), 4000, replace=False)
    dist, _ = cKDTree(desk).query(desk[idx], k=2)
    assert 0.4e-3 < np.median(dist[:, 1]) < 0.6e-3
    assert 0.4e-3 < np.mean(dist[:, 1]) < 0.6e-3


def test_whole_desk_in_view():
    for name in PAPER_SCENE_NAMES:
        camera, shapes = scene_geometry(name)
        desk = shapes[0]
        corners = desk.to_world(
            np.array([[sx * desk.length / 2, sy * desk.width / 2, 0.0]
                      for sx in (-1, 1) for sy in (-1, 1)])
        )
        uv = camera.project(corners)
        assert np.all((uv >= 0) & (uv <= [camera.width - 1, camera.height - 1]))


def gt_support(obj: GroundTruthObject, u: np.ndarray) -> float:
    """max_{p in object} p . u from the ground truth alone (independent of shapes)."""
    ul = obj.rotation.T @ u
    d = obj.dimensions
    c = float(obj.center @ u)
    if obj.type == "plane":
        return c + d["length"] / 2 * abs(ul[0]) + d["width"] / 2 * abs(ul[1])
    if obj.type == "cuboid":
        return c + np.abs(ul) @ np.array([d["length"], d["width"], d["height"]]) / 2
    radial = np.hypot(ul[0], ul[1])
    if obj.type == "cylinder":
        return c + d["height"] / 2 * abs(ul[2]) + d["radius"] * radial
    if obj.type == "cone":
        return c + max(d["height"] / 2 * ul[2], -d["height"] / 2 * ul[2] + d["radius"] * radial)
    if obj.type == "sphere":
        return c + d["radius"]
    if obj.type == "torus":
        return c + d["major_radius"] * radial + d["minor_radius"]
    raise AssertionError(obj.type)


def gt_bounding_radius(obj: GroundTruthObject) -> float:
    d = obj.dimensions
    if obj.type == "cuboid":
        return float(np.linalg.norm([d["length"], d["width"], d["height"]])) / 2
    if obj.type in ("cylinder", "cone"):
        return float(np.hypot(d["radius"], d["height"] / 2))
    if obj.type == "sphere":
        return d["radius"]
    if obj.type == "torus":
        return d["major_radius"] + d["minor_radius"]
    raise AssertionError(obj.type)


EXPECTED_TYPES = {
    "scene1": ["plane"] + ["cuboid"] * 4,
    "scene2": ["plane", "sphere", "sphere", "cylinder", "cylinder", "cone"],
    "scene3": ["plane", "cuboid", "cuboid", "cylinder", "cylinder", "cone", "sphere", "sphere"],
    "torus": ["plane", "torus", "cuboid"],
}


# Scenes whose objects touch or stack by design; test_segmentation.py checks their contacts.
CONTACT_SCENES = ("touching", "stacked")


@pytest.mark.parametrize("name", [n for n in SCENE_NAMES if n not in CONTACT_SCENES])
def test_ground_truth_consistency(name):
    camera, shapes = scene_geometry(name)
    objects = [s.ground_truth(i) for i, s in enumerate(shapes)]
    if name in EXPECTED_TYPES:
        assert [o.type for o in objects] == EXPECTED_TYPES[name]
    desk = objects[0]
    assert desk.type == "plane" and desk.id == 0
    assert desk.dimensions == {"length": 0.4, "width": 0.4}
    n = desk.rotation[:, 2]
    np.testing.assert_allclose(n, np.array([0, -0.766, -0.643]) / np.hypot(0.766, 0.643),
                               atol=1e-12)
    assert n @ desk.center < 0  # faces the camera
    np.testing.assert_allclose(desk.center, [-0.009030, -0.043117, 0.518281], atol=1e-12)
    offset = n @ desk.center
    ex, ey = desk.rotation[:, 0], desk.rotation[:, 1]
    for obj, shape in zip(objects, shapes):
        np.testing.assert_allclose(obj.rotation.T @ obj.rotation, np.eye(3), atol=1e-12)
        assert np.linalg.det(obj.rotation) > 0
        json.dumps(obj.to_dict())
        if obj.id == 0:
            continue
        # rests on the desk: lowest point exactly on the desk plane
        lowest = -gt_support(obj, -n)
        assert abs(lowest - offset) < 1e-6
        assert abs(-shape.support(-n) - offset) < 1e-6
        # footprint fully inside the desk
        for u in (ex, -ex, ey, -ey):
            assert gt_support(obj, u) - desk.center @ u <= 0.2 + 1e-12
    # pairwise disjoint (bounding spheres do not even touch)
    objs = objects[1:]
    for i in range(len(objs)):
        for j in range(i + 1, len(objs)):
            gap = np.linalg.norm(objs[i].center - objs[j].center)
            assert gap > gt_bounding_radius(objs[i]) + gt_bounding_radius(objs[j]) + 1e-3


def test_ground_truth_conventions_scene3():
    scene = render_scene("scene3")
    objs = scene.objects
    n = objs[0].rotation[:, 2]
    assert [o.id for o in objs] == list(range(8))
    cube, cuboid, cyl, lying, cone, s30, s25 = objs[1:]
    assert cube.dimensions == pytest.approx({"length": 0.05, "width": 0.05, "height": 0.05})
    assert cuboid.dimensions == pytest.approx({"length": 0.12, "width": 0.12, "height": 0.04})
    assert abs(cuboid.rotation[:, 2] @ n) == pytest.approx(1.0)
    assert cyl.dimensions == pytest.approx({"radius": 0.05, "height": 0.06})
    assert abs(cyl.rotation[:, 2] @ n) == pytest.approx(1.0)
    assert lying.dimensions == pytest.approx({"radius": 0.02, "height": 0.08})
    assert abs(lying.rotation[:, 2] @ n) < 1e-12  # axis parallel to the desk
    assert cone.rotation[:, 2] @ n == pytest.approx(1.0)  # base -> apex points up
    assert (s30.type, s30.dimensions["radius"]) == ("sphere", 0.03)
    assert (s25.type, s25.dimensions["radius"]) == ("sphere", 0.025)
    d = cube.to_dict()
    assert set(d) == {"id", "type", "center", "rotation", "dimensions"}
    assert isinstance(d["center"][0], float) and len(d["rotation"]) == 3


def test_scene3_direct_render_matches_scene():
    camera, shapes = scene_geometry("scene3")
    organized, _ = camera.render(shapes)
    assert np.isfinite(organized).all(axis=2).sum() == len(render_scene("scene3").points)


def test_scene_arrays_are_fresh_copies():
    a = render_scene("tiny_box")
    a.organized[:] = 0.0
    a.label_image[:] = 7
    b = render_scene("tiny_box")
    assert np.isnan(b.organized).any() and (b.label_image != 7).any()


# --------------------------------------------------------------------------- noise
def test_noise_sigma_along_the_ray():
    clean = render_scene("tiny_shapes")
    noise = NoiseModel(sigma_at_0_5m=0.004)
    noisy = render_scene("tiny_shapes", noise=noise, rng=11)
    assert np.array_equal(noisy.label_image, clean.label_image)
    p, q = clean.points, noisy.points
    r_clean = np.linalg.norm(p, axis=1)
    # displacement is along the viewing ray
    np.testing.assert_allclose(q / np.linalg.norm(q, axis=1, keepdims=True),
                               p / r_clean[:, None], atol=1e-12)
    residual = np.linalg.norm(q, axis=1) - r_clean
    normalised = residual / (0.004 * (p[:, 2] / 0.5) ** 2)
    assert abs(normalised.mean()) < 0.05
    assert normalised.std() == pytest.approx(1.0, abs=0.05)


def test_dropout_fraction_and_holes():
    clean = render_scene("tiny_shapes")
    n = len(clean.points)
    noisy = render_scene("tiny_shapes", noise=NoiseModel(dropout=0.1), rng=2)
    assert len(noisy.points) == n - round(0.1 * n)
    np.testing.assert_array_equal(noisy.points, clean.organized[noisy.valid_mask])  # no sigma
    assert np.array_equal(noisy.label_image >= 0, noisy.valid_mask)
    holed = render_scene("tiny_shapes", noise=NoiseModel(holes=4), rng=2)
    assert len(holed.points) < n
    assert np.array_equal(holed.label_image >= 0, holed.valid_mask)


def test_noise_is_reproducible(paper_scenes):
    a = render_scene("scene3", noise=SENSOR_NOISE, rng=42)
    b = render_scene("scene3", noise=SENSOR_NOISE, rng=np.random.default_rng(42))
    c = render_scene("scene3", noise=SENSOR_NOISE, rng=43)
    assert np.array_equal(a.organized, b.organized, equal_nan=True)
    assert np.array_equal(a.label_image, b.label_image)
    assert not np.array_equal(a.organized, c.organized, equal_nan=True)
    n = len(paper_scenes["scene3"].points)
    assert len(a.points) == n - round(0.02 * n)
    # the cached clean render is untouched
    assert np.array_equal(render_scene("scene3").organized, paper_scenes["scene3"].organized,
                          equal_nan=True)


# --------------------------------------------------------------------------- errors
def test_invalid_arguments():
    with pytest.raises(ValueError, match="allowed names: .*scene1"):
        render_scene("scene4")
    with pytest.raises(ValueError, match=r"\[0, inf\)"):
        NoiseModel(sigma_at_0_5m=-0.001)
    for bad in (-0.1, 1.0, 1.5):
        with pytest.raises(ValueError, match=r"\[0, 1\)"):
            NoiseModel(dropout=bad)
    with pytest.raises(ValueError, match=r"\[0, inf\)"):
        NoiseModel(holes=-1)
    with pytest.raises(ValueError, match="NoiseModel"):
        render_scene("tiny_box", noise=0.001)
    with pytest.raises(ValueError, match=r"\(0, inf\)"):
        Sphere(-0.01)
    with pytest.raises(ValueError, match=r"\(0, inf\)"):
        Box(0.1, 0.0, 0.1)
    with pytest.raises(ValueError, match=r"\(0, major_radius\)"):
        Torus(0.02, 0.03)
    with pytest.raises(ValueError, match="rotation"):
        Sphere(0.01, rotation=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match=r"\(0, inf\)"):
        PinholeCamera(fx=0.0, fy=1.0, cx=0.0, cy=0.0, width=10, height=10)
    with pytest.raises(ValueError, match=r"\[1, inf\)"):
        PinholeCamera(fx=1.0, fy=1.0, cx=0.0, cy=0.0, width=0, height=10)
    with pytest.raises(ValueError, match="type must be one of"):
        GroundTruthObject(id=1, type="blob", center=np.zeros(3), rotation=np.eye(3), dimensions={})

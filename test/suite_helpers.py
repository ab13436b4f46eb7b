"""The sensor suite's scenes modeled from their true labels, for end-to-end modeling tests."""

import numpy as np

from geomodel_ros.core.modeling import model_objects, model_scene
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.tools.synth.suite import SuiteCase, render_case


def suite_true_labels(layout, distance, noise="kinect-real", seed=1, params=None):
    """Model a suite case from its true labels, the desk's least-squares plane as support.

    Returns the objects by id, the ground-truth objects by id and the ModelingResult.
    """
    scene = render_case(SuiteCase(layout, distance, noise, seed))
    ok = np.all(np.isfinite(scene.points), axis=1)
    desk = scene.points[ok & (scene.labels == 0)]
    c = desk.mean(axis=0)
    n = np.linalg.svd(desk - c, full_matrices=False)[2][2]
    n = -n if n @ c > 0 else n
    result = model_objects(scene.points, np.where(ok, scene.labels, -1),
                           params or ModelingParams(), supports={0: (n, float(-n @ c))})
    return {o.id: o for o in result.objects}, {g.id: g for g in scene.objects}, result


def best_object(scene, gt_id, params=None):
    """Model a rendered scene end to end; return the object of most of ``gt_id``'s pixels.

    ``scene``: a rendered scene with its organized cloud and label image
    (:mod:`geomodel_ros.tools.synth`); fails when none of the object's pixels was segmented.
    """
    return best_object_and_labels(scene, gt_id, params)[0]


def best_object_and_labels(scene, gt_id, params=None):
    """:func:`best_object` with the frame's labels (one per pixel, row-major)."""
    labels, result = model_scene(scene.organized, params or ModelingParams())
    mine = labels[(scene.label_image.ravel() == gt_id) & (labels >= 0)]
    assert len(mine), "the object was not segmented at all"
    return {o.id: o for o in result.objects}[int(np.bincount(mine).argmax())], labels


def can_cylinder(scene, gt_id, tol_radius, tol_height):
    """Return the object modeled of can ``gt_id``, asserting a cylinder of its size.

    Its radius and height within ``tol_radius`` and ``tol_height`` [m] of the rendered
    can's (:func:`best_object`).
    """
    assert scene.kinds[gt_id] == "can"
    obj = best_object(scene, gt_id)
    assert obj.type == "cylinder", obj.reason
    truth = scene.objects[gt_id].dimensions
    assert abs(obj.dimensions["radius"] - truth["radius"]) <= tol_radius, obj.dimensions
    assert abs(obj.dimensions["height"] - truth["height"]) <= tol_height, obj.dimensions
    return obj


def scene_iou(labels, scene, gt_id, obj_id):
    """Return the IoU of rendered object ``gt_id``'s pixels and those labelled ``obj_id``."""
    gt = scene.label_image.ravel() == gt_id
    mine = labels == obj_id
    return np.count_nonzero(gt & mine) / np.count_nonzero(gt | mine)


def box_sizes(obj):
    """Return a cuboid's three sizes, sorted [m]."""
    return sorted(obj.dimensions[k] for k in ("length", "width", "height"))

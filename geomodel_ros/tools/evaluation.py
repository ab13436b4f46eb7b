"""Comparison of modeled primitives with ground truth (benchmarks and tests)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from geomodel_ros.core.decimation import decimate, spread_labels
from geomodel_ros.core.geometry import perpendicular_basis
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.primitives import Primitive
from geomodel_ros.core.segmentation import Segmentation, segment_scene

__all__ = ["expected_type", "DimensionError", "dimension_errors", "ObjectScore", "score_objects",
           "AxisFit", "circle_along", "scan_axis", "segment_frame"]


def segment_frame(organized: np.ndarray, params: ModelingParams) -> Segmentation:
    """Segment an (H, W, 3) frame as ``model_scene`` does with ``params.decimation``.

    With a decimation d > 1 the frame's samples are segmented and every pixel labelled from
    them (:mod:`geomodel_ros.core.decimation`): the labels are the frame's (H * W,).
    """
    if params.decimation <= 1:
        return segment_scene(organized, params)
    h, w = organized.shape[:2]
    flat = organized.reshape(-1, 3)
    dec = decimate(flat, (h, w), params.decimation)
    seg = segment_scene(dec.points, params, organized_shape=dec.shape)
    return dataclasses.replace(seg, labels=spread_labels(
        flat, (h, w), dec, seg.labels, params.seg_voxel_size, params.seg_max_edge_factor))


def expected_type(gt_type: str) -> str:
    """Return the type the modeling must output for a ground-truth type (else unknown)."""
    return gt_type if gt_type in ("plane", "cuboid", "cylinder", "cone", "sphere",
                                  "frustum") else "unknown"


@dataclass(frozen=True)
class DimensionError:
    """One size: name, true and estimated value and signed error, all [m]."""

    name: str
    true: float
    estimate: float

    @property
    def error(self) -> float:
        return self.estimate - self.true


def dimension_errors(est: Primitive, gt) -> list[DimensionError]:
    """Sizes of ``est`` against ground truth ``gt`` (a ``GroundTruthObject``).

    Planes and cuboids are compared axis by axis: each estimated axis is paired with the
    ground-truth axis closest to it, so the result does not depend on how the axes are
    named; the other types by name (a frustum's ``radius``, ``top_radius``, ``height``).
    Empty when the types differ.
    """
    if est.type != gt.type:
        return []
    if est.type in ("plane", "cuboid"):
        names = ("length", "width", "height")[: len(est.dimensions)]
        gnames = ("length", "width", "height")[: len(gt.dimensions)]
        cos = np.abs(est.rotation[:, : len(names)].T @ np.asarray(gt.rotation)[:, : len(gnames)])
        out = []
        for a, name in enumerate(names):
            true = float(gt.dimensions[gnames[int(np.argmax(cos[a]))]])
            out.append(DimensionError(name, true, float(est.dimensions[name])))
        return out
    true = dict(gt.dimensions)
    if est.type == "frustum" and "top_radius" in true:
        # A frustum's ``radius`` is its larger circle's (the base; a bowl stands on its
        # smaller one), ``top_radius`` the smaller's.
        true["radius"], true["top_radius"] = (max(true["radius"], true["top_radius"]),
                                              min(true["radius"], true["top_radius"]))
    return [DimensionError(k, float(true[k]), float(v))
            for k, v in est.dimensions.items() if k in true]


@dataclass(frozen=True)
class ObjectScore:
    """Score of one ground-truth object."""

    gt_id: int
    true_type: str
    expected: str
    estimated: str
    errors: tuple[DimensionError, ...]

    @property
    def type_correct(self) -> bool:
        return self.expected == self.estimated


def score_objects(estimates: list[Primitive], ground_truth) -> list[ObjectScore]:
    """Score estimates (matched to ground truth by id) object by object."""
    by_id = {p.id: p for p in estimates}
    scores = []
    for gt in ground_truth:
        est = by_id.get(gt.id)
        estimated = est.type if est is not None else "missing"
        errors = tuple(dimension_errors(est, gt)) if est is not None else ()
        scores.append(ObjectScore(gt.id, gt.type, expected_type(gt.type), estimated, errors))
    return scores


@dataclass(frozen=True)
class SegmentScore:
    """Segmentation quality of one ground-truth object.

    Attributes
    ----------
    gt_id : int
    iou : float
        Best intersection-over-union with any predicted segment (0 if all its points are
        noise).
    under : bool
        Its best segment also holds more than ``share`` of another ground-truth object.
    over : bool
        Two or more segments each hold at least ``share`` of its points.
    parts_iou : float
        IoU of the union of all segments lying mostly (> 80 %) inside the object: an
        occluded object seen as disjoint parts, each its own segment, scores 1 here.
    segment : int
        The predicted label of that best segment (-1 if all its points are noise).
    """

    gt_id: int
    iou: float
    under: bool
    over: bool
    parts_iou: float = 0.0
    segment: int = -1


def segmentation_scores(pred: np.ndarray, gt: np.ndarray, object_ids, share: float = 0.2
                        ) -> list[SegmentScore]:
    """Per-object best-match IoU, under- and over-segmentation.

    Parameters
    ----------
    pred, gt : (N,) int arrays
        Predicted and true labels per point (-1 = none).
    object_ids : iterable of int
        Ground-truth ids to score (e.g. the objects, without the table).
    share : float
        Fraction of an object's points that counts as a real part of a segment.
    """
    pred = np.asarray(pred)
    gt = np.asarray(gt)
    valid = (pred >= 0) & (gt >= 0)
    # Contingency table via one bincount over (gt, pred) pairs.
    g_ids, g_inv = np.unique(gt[valid], return_inverse=True)
    p_ids, p_inv = np.unique(pred[valid], return_inverse=True)
    table = np.bincount(g_inv * len(p_ids) + p_inv, minlength=len(g_ids) * len(p_ids)
                        ).reshape(len(g_ids), len(p_ids))
    gt_size = {int(g): int((gt == g).sum()) for g in object_ids}
    pred_size = np.bincount(p_inv, minlength=len(p_ids))
    row_of = {int(g): i for i, g in enumerate(g_ids)}
    scores = []
    for g in object_ids:
        g = int(g)
        if g not in row_of or table[row_of[g]].max() == 0:
            scores.append(SegmentScore(g, 0.0, False, False, 0.0))
            continue
        row = table[row_of[g]]
        b = int(np.argmax(row))
        inter = int(row[b])
        iou = inter / (gt_size[g] + int(pred_size[b]) - inter)
        others = [o for o in object_ids if int(o) != g and int(o) in row_of
                  and table[row_of[int(o)], b] > share * gt_size[int(o)]]
        over = int(np.sum(row >= share * gt_size[g])) >= 2
        inside = row > 0.8 * pred_size
        inside[b] = True
        union_inter = int(row[inside].sum())
        parts_iou = union_inter / (gt_size[g] + int(pred_size[inside].sum()) - union_inter)
        scores.append(SegmentScore(g, float(iou), bool(others), bool(over), float(parts_iou),
                                    int(p_ids[b])))
    return scores


@dataclass(frozen=True)
class AxisFit:
    """How well a circle fits a cloud seen along one axis direction.

    Attributes
    ----------
    direction : (3,) unit vector
    share : float
        Fraction of the points within the threshold of the best circle.
    median_residual : float [m]
        Median distance of the points from that circle (radially).
    radius : float [m]
    """

    direction: np.ndarray
    share: float
    median_residual: float
    radius: float


def circle_along(points: np.ndarray, direction: np.ndarray, threshold: float,
                 rounds: int = 6) -> AxisFit:
    """Fit the best circle through ``points`` (N, 3) projected along ``direction``.

    An algebraic (Kasa) circle refitted on the points near it, the band narrowing to
    ``threshold`` [m] over ``rounds`` rounds (handles and strays drop out).
    """
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    a, b = perpendicular_basis(d)
    q = points - points.mean(axis=0)
    x, y = q @ a, q @ b
    keep = np.ones(len(q), dtype=bool)
    r, radius = np.hypot(x, y), 0.0
    band = max(float(np.ptp(r)), threshold) if len(q) else threshold
    for _ in range(rounds):
        if keep.sum() < 3:
            break
        lhs = np.column_stack([x[keep], y[keep], np.ones(int(keep.sum()))])
        c = np.linalg.lstsq(lhs, x[keep] ** 2 + y[keep] ** 2, rcond=None)[0]
        cx, cy = c[0] / 2.0, c[1] / 2.0
        radius = float(np.sqrt(max(c[2] + cx * cx + cy * cy, 0.0)))
        r = np.abs(np.hypot(x - cx, y - cy) - radius)
        band = max(band / 2.0, threshold)
        keep = r <= band
    return AxisFit(d, float(np.mean(r <= threshold)), float(np.median(r)), radius)


def scan_axis(points: np.ndarray, around: np.ndarray, max_angle: float, threshold: float,
              step: float = np.radians(1.0)) -> list[AxisFit]:
    """Run :func:`circle_along` for directions up to ``max_angle`` [rad] from ``around``.

    Directions are ``step`` [rad] apart in polar angle and about ``step`` along the circles;
    the fits are returned best share first.
    """
    z = np.asarray(around, dtype=np.float64)
    z = z / np.linalg.norm(z)
    e1, e2 = perpendicular_basis(z)
    fits = []
    for theta in np.arange(0.0, max_angle + 1e-12, step):
        turns = max(1, int(np.ceil(2.0 * np.pi * np.sin(theta) / step)))
        for phi in np.arange(turns) * (2.0 * np.pi / turns):
            d = np.cos(theta) * z + np.sin(theta) * (np.cos(phi) * e1 + np.sin(phi) * e2)
            fits.append(circle_along(points, d, threshold))
    return sorted(fits, key=lambda f: (-f.share, f.median_residual))

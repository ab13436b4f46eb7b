"""Comparison of modeled primitives with ground truth (benchmarks and tests)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .primitives import Primitive

__all__ = ["expected_type", "DimensionError", "dimension_errors", "ObjectScore", "score_objects"]


def expected_type(gt_type: str) -> str:
    """The type the modeling must output for a ground-truth type (irregular -> unknown)."""
    return gt_type if gt_type in ("plane", "cuboid", "cylinder", "cone", "sphere") else "unknown"


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
    named. Empty when the types differ.
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
    return [DimensionError(k, float(gt.dimensions[k]), float(v))
            for k, v in est.dimensions.items() if k in gt.dimensions]


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

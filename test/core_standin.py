"""Test-only stand-in for :func:`geomodel_ros.pipeline.model_scene`.

Scene segmentation is being written; until ``model_scene`` exists in the pipeline the node
tests use this stand-in, which recovers each point's object from the ground truth of the
synthetic scene it was rendered from (nearest rendered point, float32 tolerance) and calls
the real :func:`~geomodel_ros.pipeline.model_objects`.  Once ``model_scene`` exists,
:func:`scene_model` returns the real one and :func:`install_if_missing` does nothing, so the
same tests then run the real core end to end.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from geomodel_ros import pipeline
from geomodel_ros.synth import render_scene

#: Scenes the stand-in can label.
SCENES = ("tiny_box", "tiny_shapes", "scene3")


class GroundTruthSceneModel:
    """``model_scene(points, params, organized_shape=None) -> (labels, ModelingResult)``."""

    def __init__(self, scenes: tuple[str, ...] = SCENES) -> None:
        self._scenes = scenes
        self._trees: dict[str, tuple[cKDTree, np.ndarray]] = {}

    def _tree(self, name: str) -> tuple[cKDTree, np.ndarray]:
        if name not in self._trees:
            scene = render_scene(name)
            pts = scene.points.astype(np.float32).astype(np.float64)  # as sent in a cloud
            self._trees[name] = (cKDTree(pts), scene.labels.astype(np.int64))
        return self._trees[name]

    def labels(self, points: np.ndarray) -> np.ndarray:
        """(N,) ground-truth object id of every point; ValueError for an unknown scene."""
        for name in self._scenes:
            tree, labels = self._tree(name)
            if len(points) != tree.n:
                continue
            dist, idx = tree.query(points, distance_upper_bound=1e-6)
            if np.all(np.isfinite(dist)):
                return labels[idx]
        raise ValueError(f"stand-in model_scene knows only the scenes {', '.join(self._scenes)}")

    def __call__(self, points, params, organized_shape=None):
        labels = self.labels(np.asarray(points, dtype=np.float64))
        return labels, pipeline.model_objects(points, labels, params)


def scene_model():
    """The real ``model_scene`` when the pipeline has it, else the ground-truth stand-in."""
    return getattr(pipeline, "model_scene", None) or GroundTruthSceneModel()


def install_if_missing() -> None:
    """Put the stand-in into ``geomodel_ros.pipeline`` unless ``model_scene`` exists."""
    if getattr(pipeline, "model_scene", None) is None:
        pipeline.model_scene = GroundTruthSceneModel()

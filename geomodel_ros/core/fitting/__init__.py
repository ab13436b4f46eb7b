"""Fitting units: one per primitive type, sharing the steps fit -> verify -> size -> orient.

Modules, in the order an object meets them:

- :mod:`.cloud`: the object prepared for fitting (working cloud, described faces);
- :mod:`.strategies`: the model graph's decision and the ordered fallbacks;
- :mod:`.units`: the unit of each :class:`~geomodel_ros.core.primitives.PrimitiveType`
  (:mod:`.plane`, :mod:`.cuboid`, :mod:`.cylinder`, :mod:`.cone`, :mod:`.sphere`,
  :mod:`.frustum`), each
  returning a :class:`~.result.Fitted` primitive or a :class:`~.result.Rejected` type;
- shared steps: :mod:`.curved` (RANSAC on curved faces, inner caps), :mod:`.verify`
  (inlier ratio, coverage, arc, bulk, apex), :mod:`.measure` (robust statistics),
  :mod:`.axial` (caps and extent along an axis), :mod:`.orient`.
"""

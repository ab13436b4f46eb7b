"""RANSAC fitters with the object type as prior (paper section 3.2).

Every model has a minimal-sample solver that uses point normals where they help
(plane: 3 points; sphere: 2 points + normals; cylinder: 2 points + normals; cone:
3 points + normals), a batched residual (hypotheses are scored many at a time), adaptive
early termination, and a least-squares refinement on the inliers
(MINPACK's Levenberg-Marquardt through :func:`scipy.optimize.leastsq`, geometric
distances so the radius is not biased by noise).

The contract between the models and :func:`ransac` / :func:`refine` is written out as
the protocols :class:`RansacModel` and :class:`RefinableModel`; every model's candidate
hypotheses travel as a typed batch (:class:`PlaneBatch`, :class:`SphereBatch`,
:class:`CylinderBatch`, :class:`ConeBatch`: NamedTuples of arrays with one row per
hypothesis).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Callable, ClassVar, Generic, NamedTuple, Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import leastsq

from geomodel_ros.core.fastmath import centroid, take_rows
from geomodel_ros.core.geometry import EPS, perpendicular_basis, unit3

__all__ = [
    "PlaneModel", "SphereModel", "CylinderModel", "ConeModel", "FitResult",
    "PlaneBatch", "SphereBatch", "CylinderBatch", "ConeBatch",
    "RansacModel", "RefinableModel", "SurfaceModel",
    "HypothesisTest", "fit_plane_svd", "ransac", "refine", "MODELS", "MAX_EVALUATIONS",
    "HYPOTHESES_PER_BATCH",
]

Array = NDArray[np.float64]

#: Two sample normals (sphere) whose lines are this close to parallel (1 - cos^2 of
#: their angle, i.e. sin^2 < 1e-6: under 0.06 deg) give no usable closest points.
_MIN_LINE_SIN2 = 1e-6
#: Cylinder axis = n1 x n2: sample normals under ~0.06 deg apart (|n1 x n2| <= 1e-3)
#: give no reliable axis direction.
_MIN_AXIS_CROSS = 1e-3
#: Cone apex = intersection of the three tangent planes: |det| of the three unit
#: normals at or below this means nearly dependent planes (an ill-conditioned apex).
_MIN_TANGENT_DET = 1e-4
#: Cone hypotheses with a half-angle outside (1e-3, 1.5) rad are a cylinder (angle ~0)
#: or a plane (angle ~90 deg), not a cone.
_CONE_ANGLE_RANGE = (1e-3, 1.5)
#: Clouds with fewer than this many points per sample point are sampled without
#: replacement (repeated points would make most minimal samples degenerate); larger
#: clouds draw with replacement, which is much faster and rarely repeats.
_DISTINCT_SAMPLING_FACTOR = 4
#: A plane refinement needs 3 inliers; curved models need their sample size plus this
#: many, so that least squares is over-determined.
_MIN_PLANE_POINTS = 3
_REFINE_EXTRA_POINTS = 3
#: Relative tolerances of MINPACK's Levenberg-Marquardt, as in
#: :func:`scipy.optimize.least_squares`.
_LSQ_TOLERANCE = 1e-8

#: Hypotheses solved and scored together by :func:`ransac`: large enough that numpy's
#: per-call overhead is small, small enough that early termination wastes few. Part of
#: the random-number order: changing it changes every fit.
HYPOTHESES_PER_BATCH = 64

#: Evaluations per least-squares refinement. With exact Jacobians a well-posed fit
#: converges in well under this (synthetic scenes: 1-11); an ill-posed one (a cone whose
#: apex runs off along a nearly cylindrical surface) would otherwise spend 200
#: evaluations going nowhere, and is judged by the verification that follows either way.
#: 30 instead of 50 changed no type on the 45 Kinect frames and no synthetic size.
MAX_EVALUATIONS = 30


def _unit(v: Array) -> Array:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > EPS, n, 1.0)


# Single models work on points transposed to (3, M): numpy is several times faster on
# long rows than on the short last axis of (M, 3), and least-squares refinement
# evaluates distances and Jacobians many times.

def _col_norms(v: Array) -> Array:
    return np.sqrt(np.einsum("im,im->m", v, v))


def _axial_parts_t(v: Array, axis: Array) -> tuple[Array, Array, Array]:
    """Split offsets from a point on a unit axis into radial and axial parts.

    Parameters
    ----------
    v : (3, M) float64 array [m]
        Offsets from a point on the axis.
    axis : (3,) float64 array, unit

    Returns
    -------
    radial : (3, M) float64 array [m]
    t : (M,) float64 array [m], axial coordinate
    rho : (M,) float64 array [m], radial distance
    """
    t = axis @ v
    radial = v - axis[:, None] * t
    return radial, t, _col_norms(radial)


def _radial_units_t(radial: Array, rho: Array) -> Array:
    return radial / np.maximum(rho, EPS)


def _batch_radial(pt: Array, origin: Array, axis: Array) -> tuple[Array, Array, Array]:
    """Radial parts of points about B axis lines.

    Parameters
    ----------
    pt : (3, M) float64 array [m]
    origin : (B, 3) float64 array [m], a point on each axis
    axis : (B, 3) float64 array, unit

    Returns
    -------
    radial : (B, 3, M) [m]; along : (B, M) [m]; rn : (B, M) [m] radial distances
    """
    v = pt[None, :, :] - origin[:, :, None]
    along = np.einsum("bim,bi->bm", v, axis)
    radial = v - along[:, None, :] * axis[:, :, None]
    rn = np.sqrt(np.einsum("bim,bim->bm", radial, radial))
    return radial, along, rn


# ----------------------------------------------------------------------------------------
# Typed candidate batches: one row per hypothesis (B rows).
# ----------------------------------------------------------------------------------------


class PlaneBatch(NamedTuple):
    """B plane hypotheses n . x + d = 0."""

    normal: Array  #: (B, 3) unit normals
    d: Array  #: (B,) offsets [m]


class SphereBatch(NamedTuple):
    """B sphere hypotheses."""

    center: Array  #: (B, 3) centres [m]
    radius: Array  #: (B,) radii [m]


class CylinderBatch(NamedTuple):
    """B infinite-cylinder hypotheses."""

    point: Array  #: (B, 3) a point on each axis [m]
    axis: Array  #: (B, 3) unit axes
    radius: Array  #: (B,) radii [m]


class ConeBatch(NamedTuple):
    """B infinite-cone hypotheses."""

    apex: Array  #: (B, 3) apexes [m]
    axis: Array  #: (B, 3) unit axes, apex -> base
    half_angle: Array  #: (B,) half-angles [rad]


BatchT = TypeVar("BatchT", PlaneBatch, SphereBatch, CylinderBatch, ConeBatch)


# ----------------------------------------------------------------------------------------
# The contract of a model
# ----------------------------------------------------------------------------------------


class SurfaceModel(Protocol):
    """A fitted surface that measures signed point distances."""

    def distance(self, p: Array) -> Array:
        """Signed distances [m] (M,) of points ``p`` (M, 3) [m] to the surface."""
        ...


class RansacModel(SurfaceModel, Protocol[BatchT]):
    """What :func:`ransac` needs of a model class.

    ``sample_size`` points (with normals) make a minimal sample; ``hypotheses`` solves B
    samples at once, ``residuals`` scores B hypotheses against all points, ``from_batch``
    makes the single model of one row.
    """

    sample_size: ClassVar[int]

    @staticmethod
    def hypotheses(p: Array, n: Array) -> BatchT:
        """Solve B minimal samples: points ``p`` and unit normals ``n``, (B, k, 3).

        Degenerate samples are dropped, so the batch may have fewer than B rows.
        """
        ...

    @staticmethod
    def residuals(h: BatchT, pt: Array, nt: Array) -> tuple[Array, Array]:
        """Distances [m] (B, M) and |cos| (B, M) of normal deviations.

        Points ``pt`` and unit normals ``nt`` are given transposed, (3, M).
        """
        ...

    @staticmethod
    def from_batch(h: BatchT, i: int) -> Any:
        """Return the model of row ``i`` of ``h`` (an instance of the class)."""
        ...


class RefinableModel(SurfaceModel, Protocol):
    """What :func:`refine` needs of a curved model (sphere, cylinder, cone).

    Parameters are perturbations ``x`` (P,) of the model itself (the reference):
    ``to_vector()`` is the reference's own vector, ``from_vector(x)`` the perturbed model
    and ``jacobian_t(x, pt)`` d distance / d x there, (P, M), for points (3, M).
    """

    sample_size: ClassVar[int]

    def distance_t(self, pt: Array) -> Array:
        """Signed distances [m] (M,) of points given transposed, (3, M)."""
        ...

    def to_vector(self) -> Array:
        """Return the parameter vector (P,) of this model."""
        ...

    def from_vector(self, x: Array) -> Any:
        """Return the model at parameter vector ``x`` (P,) (same class)."""
        ...

    def jacobian_t(self, x: Array, pt: Array) -> Array:
        """Return d distance / d x (P, M) at ``from_vector(x)`` for points (3, M)."""
        ...

    def parts_t(self, pt: Array) -> Any:
        """Return what the distances and the Jacobian of points (3, M) share."""
        ...

    def distance_from(self, parts: Any) -> Array:
        """Return :meth:`distance_t` of the points whose :meth:`parts_t` are ``parts``."""
        ...

    def jacobian_from(self, x: Array, m: Any, parts: Any) -> Array:
        """Return :meth:`jacobian_t` at ``x`` from ``m = from_vector(x)`` and ``m.parts_t``."""
        ...


# ----------------------------------------------------------------------------------------
# Models
# ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PlaneModel:
    """Plane n . x + d = 0 with unit normal ``n`` (3,) and offset ``d`` [m]."""

    normal: Array
    d: float

    sample_size: ClassVar[int] = 3

    @staticmethod
    def hypotheses(p: Array, n: Array) -> PlaneBatch:  # noqa: ARG004 (protocol signature)
        """Planes through three points ``p`` (B, 3, 3) [m]; normals are not needed."""
        nrm = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        ok = np.linalg.norm(nrm, axis=1) > EPS
        nrm = _unit(nrm)
        return PlaneBatch(nrm[ok], -np.einsum("bi,bi->b", nrm, p[:, 0])[ok])

    @staticmethod
    def residuals(h: PlaneBatch, pt: Array, nt: Array) -> tuple[Array, Array]:
        """Signed distances (B, M) [m] and |cos| (B, M) to ``pt``, ``nt`` (3, M)."""
        dist = h.normal @ pt + h.d[:, None]
        cos = np.abs(h.normal @ nt)
        return dist, cos

    def distance(self, p: Array) -> Array:
        """Signed distances (M,) [m] of ``p`` (M, 3) [m]."""
        return p @ self.normal + self.d

    @staticmethod
    def from_batch(h: PlaneBatch, i: int) -> PlaneModel:
        """Return the plane of row ``i``."""
        return PlaneModel(h.normal[i].copy(), float(h.d[i]))


@dataclass(frozen=True)
class SphereModel:
    """Sphere with centre (3,) [m] and radius [m]."""

    center: Array
    radius: float

    sample_size: ClassVar[int] = 2

    @staticmethod
    def hypotheses(p: Array, n: Array) -> SphereBatch:
        """Spheres from two points ``p`` and normals ``n`` (B, 2, 3).

        The centre is the midpoint of the closest points of the two normal lines
        p_i + t n_i; the radius the mean distance of the two points from it.
        """
        d1, d2 = n[:, 0], n[:, 1]
        w = p[:, 0] - p[:, 1]
        a = np.einsum("bi,bi->b", d1, d1)
        b = np.einsum("bi,bi->b", d1, d2)
        c = np.einsum("bi,bi->b", d2, d2)
        d = np.einsum("bi,bi->b", d1, w)
        e = np.einsum("bi,bi->b", d2, w)
        den = a * c - b * b
        ok = den > _MIN_LINE_SIN2
        den = np.where(ok, den, 1.0)
        t = (b * e - c * d) / den
        s = (a * e - b * d) / den
        c1 = p[:, 0] + t[:, None] * d1
        c2 = p[:, 1] + s[:, None] * d2
        center = 0.5 * (c1 + c2)
        r = 0.5 * (np.linalg.norm(p[:, 0] - center, axis=1)
                   + np.linalg.norm(p[:, 1] - center, axis=1))
        return SphereBatch(center[ok], r[ok])

    @staticmethod
    def residuals(h: SphereBatch, pt: Array, nt: Array) -> tuple[Array, Array]:
        """Signed distances (B, M) [m] and |cos| (B, M) to ``pt``, ``nt`` (3, M)."""
        diff = pt[None, :, :] - h.center[:, :, None]
        norm = np.sqrt(np.einsum("bim,bim->bm", diff, diff))
        dist = norm - h.radius[:, None]
        cos = np.abs(np.einsum("bim,im->bm", diff, nt)) / np.maximum(norm, EPS)
        return dist, cos

    def distance(self, p: Array) -> Array:
        """Signed distances (M,) [m] of ``p`` (M, 3) [m] (positive outside)."""
        return self.distance_t(p.T)

    def distance_t(self, pt: Array) -> Array:
        """:meth:`distance` of points given as (3, M)."""
        return self.distance_from(self.parts_t(pt))

    def parts_t(self, pt: Array) -> tuple[Array, Array]:
        """Offsets (3, M) [m] of points (3, M) from the centre, and their lengths (M,) [m].

        What :meth:`distance_from` and :meth:`jacobian_from` share.
        """
        v = pt - self.center[:, None]
        return v, _col_norms(v)

    def distance_from(self, parts: tuple[Array, Array]) -> Array:
        """Return :meth:`distance_t` of the points whose :meth:`parts_t` are ``parts``."""
        return parts[1] - self.radius

    @staticmethod
    def from_batch(h: SphereBatch, i: int) -> SphereModel:
        """Return the sphere of row ``i``."""
        return SphereModel(h.center[i].copy(), float(h.radius[i]))

    def to_vector(self) -> Array:
        """Return (centre x, y, z [m], radius [m])."""
        return np.r_[self.center, self.radius]

    def from_vector(self, x: Array) -> SphereModel:
        """Return the sphere of the vector ``x`` (4,) (absolute: centre, radius)."""
        return SphereModel(x[:3].copy(), float(x[3]))

    def jacobian(self, x: Array, p: Array) -> Array:
        """Return d distance(p) / d x at ``from_vector(x)``, shape (M, 4)."""
        return self.jacobian_t(x, p.T).T

    def jacobian_t(self, x: Array, pt: Array) -> Array:
        """Return :meth:`jacobian` transposed, (P, M), for points given as (3, M)."""
        m = self.from_vector(x)
        return self.jacobian_from(x, m, m.parts_t(pt))

    def jacobian_from(self, x: Array, m: SphereModel,  # noqa: ARG002 (protocol signature)
                      parts: tuple[Array, Array]) -> Array:
        """Return :meth:`jacobian_t` at ``x`` given ``m = from_vector(x)`` and its ``parts``."""
        v, norms = parts
        u = v / np.maximum(norms, EPS)
        jt = np.empty((4, v.shape[1]))
        np.negative(u, out=jt[:3])
        jt[3] = -1.0
        return jt


@dataclass(frozen=True)
class CylinderModel:
    """Infinite cylinder: point on the axis (3,) [m], unit axis (3,), radius [m]."""

    point: Array
    axis: Array
    radius: float

    sample_size: ClassVar[int] = 2

    @staticmethod
    def hypotheses(p: Array, n: Array) -> CylinderBatch:
        """Cylinders from two points ``p`` and normals ``n`` (B, 2, 3).

        The axis is n1 x n2. In the plane perpendicular to it (the second point and both
        normals projected onto it) the two normal lines meet at the centre.
        """
        axis = np.cross(n[:, 0], n[:, 1])
        ok = np.linalg.norm(axis, axis=1) > _MIN_AXIS_CROSS
        axis = _unit(axis)

        def flat(v: Array) -> Array:
            """Remove the axial component of ``v`` (B, 3)."""
            return v - np.einsum("bi,bi->b", v, axis)[:, None] * axis

        q1, q2 = p[:, 0], flat(p[:, 1] - p[:, 0]) + p[:, 0]
        m1, m2 = _unit(flat(n[:, 0])), _unit(flat(n[:, 1]))
        # Intersect q1 + t m1 and q2 + s m2 (least squares in 3-D, lines are coplanar).
        w = q1 - q2
        b = np.einsum("bi,bi->b", m1, m2)
        d = np.einsum("bi,bi->b", m1, w)
        e = np.einsum("bi,bi->b", m2, w)
        den = 1.0 - b * b
        ok &= den > _MIN_LINE_SIN2
        den = np.where(ok, den, 1.0)
        t = (b * e - d) / den
        s = (e - b * d) / den
        center = 0.5 * (q1 + t[:, None] * m1 + q2 + s[:, None] * m2)
        r = 0.5 * (np.linalg.norm(q1 - center, axis=1) + np.linalg.norm(q2 - center, axis=1))
        return CylinderBatch(center[ok], axis[ok], r[ok])

    @staticmethod
    def residuals(h: CylinderBatch, pt: Array, nt: Array) -> tuple[Array, Array]:
        """Signed distances (B, M) [m] and |cos| (B, M) to ``pt``, ``nt`` (3, M).

        The surface normal at a point is its radial direction.
        """
        radial, _, rn = _batch_radial(pt, h.point, h.axis)
        dist = rn - h.radius[:, None]
        cos = np.abs(np.einsum("bim,im->bm", radial, nt)) / np.maximum(rn, EPS)
        return dist, cos

    def distance(self, p: Array) -> Array:
        """Signed distances (M,) [m] of ``p`` (M, 3) [m] (positive outside)."""
        return self.distance_t(p.T)

    def distance_t(self, pt: Array) -> Array:
        """:meth:`distance` of points given as (3, M)."""
        return self.distance_from(self.parts_t(pt))

    def parts_t(self, pt: Array) -> tuple[Array, Array, Array]:
        """Radial parts (3, M), axial coordinates (M,) and radial distances (M,) [m].

        Of points (3, M) about the axis (:func:`_axial_parts_t`); what
        :meth:`distance_from` and :meth:`jacobian_from` share.
        """
        return _axial_parts_t(pt - self.point[:, None], self.axis)

    def distance_from(self, parts: tuple[Array, Array, Array]) -> Array:
        """Return :meth:`distance_t` of the points whose :meth:`parts_t` are ``parts``."""
        return parts[2] - self.radius

    @staticmethod
    def from_batch(h: CylinderBatch, i: int) -> CylinderModel:
        """Return the cylinder of row ``i``."""
        return CylinderModel(h.point[i].copy(), h.axis[i].copy(), float(h.radius[i]))

    @cached_property
    def basis(self) -> tuple[Array, Array]:
        """Unit vectors ``e1, e2`` (3,) perpendicular to the axis (:func:`perpendicular_basis`).

        Computed once per model: a least-squares refinement perturbs one model through
        :meth:`from_vector` and :meth:`jacobian_t` at every evaluation.
        """
        return perpendicular_basis(self.axis)

    def to_vector(self) -> Array:
        """Return zeros (5,): x perturbs this model (axis tilt 2, axis shift 2, radius)."""
        return np.zeros(5)

    def from_vector(self, x: Array) -> CylinderModel:
        """Return this cylinder with axis tilt x[:2], shift x[2:4] [m], radius + x[4] [m]."""
        e1, e2 = self.basis
        axis = unit3(self.axis + x[0] * e1 + x[1] * e2)
        point = self.point + x[2] * e1 + x[3] * e2
        return CylinderModel(point, axis, float(self.radius + x[4]))

    def jacobian(self, x: Array, p: Array) -> Array:
        """Return d distance(p) / d x at ``from_vector(x)``, shape (M, 5)."""
        return self.jacobian_t(x, p.T).T

    def jacobian_t(self, x: Array, pt: Array) -> Array:
        """Return :meth:`jacobian` transposed, (P, M), for points given as (3, M)."""
        m = self.from_vector(x)
        return self.jacobian_from(x, m, m.parts_t(pt))

    def jacobian_from(self, x: Array, m: CylinderModel,  # noqa: ARG002 (protocol signature)
                      parts: tuple[Array, Array, Array]) -> Array:
        """Return :meth:`jacobian_t` at ``x`` given ``m = from_vector(x)`` and its ``parts``."""
        e1, e2 = self.basis
        scale = float(np.linalg.norm(self.axis + x[0] * e1 + x[1] * e2))
        radial, t, rho = parts
        u = _radial_units_t(radial, rho)
        jt = np.empty((5, t.shape[0]))
        np.negative(e1 @ u, out=jt[2])
        np.negative(e2 @ u, out=jt[3])
        np.multiply(jt[2], t, out=jt[0])
        np.multiply(jt[3], t, out=jt[1])
        jt[:2] /= scale
        jt[4] = -1.0
        return jt


@dataclass(frozen=True)
class ConeModel:
    """Infinite cone: apex (3,) [m], unit axis (3,), half-angle [rad].

    The axis points from the apex into the cone (apex -> base).
    """

    apex: Array
    axis: Array
    half_angle: float

    sample_size: ClassVar[int] = 3

    @staticmethod
    def hypotheses(p: Array, n: Array) -> ConeBatch:
        """Cones from three points ``p`` and normals ``n`` (B, 3, 3).

        The apex is the common point of the three tangent planes n_i . (x - p_i) = 0;
        the axis is normal to the plane of the three unit directions apex -> p_i.
        """
        rhs = np.einsum("bki,bki->bk", n, p)
        det = np.linalg.det(n)
        ok = np.abs(det) > _MIN_TANGENT_DET
        nn = np.where(ok[:, None, None], n, np.eye(3)[None])
        apex = np.linalg.solve(nn, rhs[..., None])[..., 0]
        e = _unit(p - apex[:, None, :])
        axis = _unit(np.cross(e[:, 1] - e[:, 0], e[:, 2] - e[:, 0]))
        flip = np.einsum("bi,bi->b", axis, e[:, 0]) < 0
        axis[flip] *= -1
        ang = np.arccos(np.clip(np.einsum("bki,bi->bk", e, axis), -1, 1)).mean(axis=1)
        ok &= (ang > _CONE_ANGLE_RANGE[0]) & (ang < _CONE_ANGLE_RANGE[1])
        return ConeBatch(apex[ok], axis[ok], ang[ok])

    @staticmethod
    def residuals(h: ConeBatch, pt: Array, nt: Array) -> tuple[Array, Array]:
        """Signed distances (B, M) [m] and |cos| (B, M) to ``pt``, ``nt`` (3, M)."""
        radial, along, rn = _batch_radial(pt, h.apex, h.axis)
        ct, st = np.cos(h.half_angle)[:, None], np.sin(h.half_angle)[:, None]
        dist = rn * ct - along * st
        # Surface normal = ct * radial unit - st * axis; its cosine with the point normal:
        cos = np.abs(ct * np.einsum("bim,im->bm", radial, nt) / np.maximum(rn, EPS)
                     - st * (h.axis @ nt))
        return dist, cos

    def distance(self, p: Array) -> Array:
        """Signed distances (M,) [m] of ``p`` (M, 3) [m] (positive outside)."""
        return self.distance_t(p.T)

    def distance_t(self, pt: Array) -> Array:
        """:meth:`distance` of points given as (3, M)."""
        return self.distance_from(self.parts_t(pt))

    def parts_t(self, pt: Array) -> tuple[Array, Array, Array, Array]:
        """Offsets, radial parts (3, M), axial coordinates, radial distances (M,) [m].

        Of points (3, M) from the apex and about the axis; what :meth:`distance_from` and
        :meth:`jacobian_from` share.
        """
        v = pt - self.apex[:, None]
        return (v, *_axial_parts_t(v, self.axis))

    def distance_from(self, parts: tuple[Array, Array, Array, Array]) -> Array:
        """Return :meth:`distance_t` of the points whose :meth:`parts_t` are ``parts``."""
        _, _, along, rn = parts
        return rn * math.cos(self.half_angle) - along * math.sin(self.half_angle)

    @staticmethod
    def from_batch(h: ConeBatch, i: int) -> ConeModel:
        """Return the cone of row ``i``."""
        return ConeModel(h.apex[i].copy(), h.axis[i].copy(), float(h.half_angle[i]))

    @cached_property
    def basis(self) -> tuple[Array, Array]:
        """Unit vectors ``e1, e2`` (3,) perpendicular to the axis (:func:`perpendicular_basis`).

        Computed once per model: a least-squares refinement perturbs one model through
        :meth:`from_vector` and :meth:`jacobian_t` at every evaluation.
        """
        return perpendicular_basis(self.axis)

    def to_vector(self) -> Array:
        """Return zeros (6,): x perturbs this model (axis tilt 2, apex 3 [m], angle [rad])."""
        return np.zeros(6)

    def from_vector(self, x: Array) -> ConeModel:
        """Return this cone with axis tilt x[:2], apex + x[2:5] [m], angle + x[5] [rad]."""
        e1, e2 = self.basis
        axis = unit3(self.axis + x[0] * e1 + x[1] * e2)
        return ConeModel(self.apex + x[2:5], axis, float(self.half_angle + x[5]))

    def jacobian(self, x: Array, p: Array) -> Array:
        """Return d distance(p) / d x at ``from_vector(x)``, shape (M, 6)."""
        return self.jacobian_t(x, p.T).T

    def jacobian_t(self, x: Array, pt: Array) -> Array:
        """Return :meth:`jacobian` transposed, (P, M), for points given as (3, M)."""
        m = self.from_vector(x)
        return self.jacobian_from(x, m, m.parts_t(pt))

    def jacobian_from(self, x: Array, m: ConeModel,
                      parts: tuple[Array, Array, Array, Array]) -> Array:
        """Return :meth:`jacobian_t` at ``x`` given ``m = from_vector(x)`` and its ``parts``."""
        e1, e2 = self.basis
        scale = float(np.linalg.norm(self.axis + x[0] * e1 + x[1] * e2))
        a = m.axis
        v, radial, t, rho = parts
        u = _radial_units_t(radial, rho)
        c, s = math.cos(m.half_angle), math.sin(m.half_angle)
        jt = np.empty((6, v.shape[1]))
        for row, e in enumerate((e1, e2)):  # axis tilts: d axis = (e - a (a . e)) / scale
            ve = (e @ v - t * float(a @ e)) / scale
            jt[row] = -c * t * (e @ u) / scale - s * ve
        np.multiply(u, -c, out=jt[2:5])
        jt[2:5] += s * a[:, None]
        jt[5] = -rho * s - t * c
        return jt


#: The model classes by type name.
MODELS: dict[str, type[PlaneModel] | type[SphereModel] | type[CylinderModel] | type[ConeModel]] = {
    "plane": PlaneModel, "sphere": SphereModel, "cylinder": CylinderModel, "cone": ConeModel,
}

ModelT = TypeVar("ModelT", PlaneModel, SphereModel, CylinderModel, ConeModel)


@dataclass(frozen=True)
class FitResult(Generic[ModelT]):
    """Best RANSAC model and its support on the points it was fitted to.

    Attributes
    ----------
    model : the fitted model
    inliers : (M,) bool array, |distance| <= threshold
    inlier_ratio : float, share of inliers
    rmse : float [m], root mean square distance of the inliers (inf without inliers)
    """

    model: ModelT
    inliers: NDArray[np.bool_]
    inlier_ratio: float
    rmse: float


def fit_plane_svd(points: Array) -> PlaneModel:
    """Total-least-squares plane through ``points`` (n >= 3, (n, 3) [m])."""
    c = centroid(points)
    q = points - c
    # Eigenvector of the smallest eigenvalue of the 3x3 scatter matrix (the last right
    # singular vector of q, without forming q's (n, 3) left singular vectors).
    _, vecs = np.linalg.eigh(q.T @ q)
    n = vecs[:, 0]
    return PlaneModel(n, float(-n @ c))


def _draw_samples(m: int, k: int, nb: int, rng: np.random.Generator) -> NDArray[np.int64]:
    """Draw ``nb`` minimal samples of ``k`` of ``m`` points: indices (nb, k)."""
    if m < _DISTINCT_SAMPLING_FACTOR * k:
        return np.stack([rng.choice(m, size=k, replace=False) for _ in range(nb)])
    return rng.integers(0, m, size=(nb, k))


@dataclass(frozen=True)
class HypothesisTest:
    """A RANSAC hypothesis test of one model (called) that also tests a batch's rows at once.

    Attributes
    ----------
    one : callable, model -> bool
    rows : callable, batch of B hypotheses -> (B,) bool array, row i equal to ``one`` of
        the batch's row i (the same comparisons, made on the batch's arrays)
    """

    one: Callable[[Any], bool]
    rows: Callable[[Any], NDArray[np.bool_]]

    def __call__(self, model: Any) -> bool:
        """Return ``one(model)``."""
        return self.one(model)


def _accepted(model_cls: type[RansacModel[BatchT]], h: BatchT,
              accept: Callable[[Any], bool] | None) -> BatchT | None:
    """Rows of ``h`` that ``accept`` keeps (``None`` when no row is left).

    A :class:`HypothesisTest` tests all the rows at once; any other callable, one
    model of each row (:meth:`RansacModel.from_batch`) after the other.
    """
    count = len(h[0])
    if count == 0:
        return None
    if accept is None:
        return h
    if isinstance(accept, HypothesisTest):
        keep = np.asarray(accept.rows(h), dtype=bool)
    else:
        keep = np.array([accept(model_cls.from_batch(h, i)) for i in range(count)])
    if not keep.any():
        return None
    return type(h)(*(values[keep] for values in h))


def _needed_iterations(inlier_share: float, k: int, confidence: float, drawn: int,
                       needed: int) -> int:
    """Hypotheses needed to draw an all-inlier sample of ``k`` with ``confidence``."""
    if inlier_share >= 1.0:
        return drawn
    if inlier_share > 0:
        return int(math.ceil(math.log(1 - confidence) / math.log(1 - inlier_share ** k)))
    return needed


def _support(model: ModelT, points: Array, threshold: float) -> FitResult[ModelT]:
    """Inliers, inlier ratio and inlier RMSE of ``model`` on ``points`` (M, 3) [m]."""
    dist = model.distance(points)
    inliers = np.abs(dist) <= threshold
    rmse = float(np.sqrt(np.mean(dist[inliers] ** 2))) if inliers.any() else float("inf")
    return FitResult(model, inliers, float(inliers.mean()), rmse)


def ransac(model_cls: type[ModelT], points: Array, normals: Array, threshold: float,
           normal_threshold: float, max_iterations: int, confidence: float,
           rng: np.random.Generator, batch: int = HYPOTHESES_PER_BATCH,
           accept: Callable[[ModelT], bool] | None = None,
           max_score_points: int | None = None) -> FitResult[ModelT] | None:
    """Find the model with the most inliers.

    Parameters
    ----------
    model_cls : a :class:`RansacModel` class (one of :data:`MODELS`' values)
    points, normals : (M, 3) float64 arrays [m], unit normals
    threshold : float [m]
        Inlier distance.
    normal_threshold : float [rad]
        Inlier normal deviation.
    max_iterations : int
        Upper bound on hypotheses; fewer are drawn once ``confidence`` is reached.
    confidence : float
        Probability of drawing at least one all-inlier sample (early termination).
    rng : numpy Generator
    batch : int
        Hypotheses solved and scored at once.
    accept : callable, optional
        Hypotheses for which it returns False are skipped (e.g. radius bounds).
    max_score_points : int, optional
        Hypotheses are scored on a random subset of this many points (large clouds);
        the returned inliers are those of all points.

    Returns
    -------
    FitResult or None when no hypothesis could be formed.
    """
    cls: type[RansacModel[Any]] = model_cls
    m, k = len(points), cls.sample_size
    if m < k + 1:
        return None
    cos_thr = math.cos(normal_threshold)
    sp, sn = points, normals
    if max_score_points is not None and m > max_score_points:
        scored = np.sort(rng.choice(m, max_score_points, replace=False))
        sp, sn = points[scored], normals[scored]
    pt, nt = np.ascontiguousarray(sp.T), np.ascontiguousarray(sn.T)
    best_count, best = -1, None
    needed, drawn = max_iterations, 0
    while drawn < min(needed, max_iterations):
        nb = min(batch, max_iterations - drawn)
        idx = _draw_samples(m, k, nb, rng)
        drawn += nb
        h = _accepted(cls, cls.hypotheses(points[idx], normals[idx]), accept)
        if h is None:
            continue
        dist, cos = cls.residuals(h, pt, nt)
        counts = ((np.abs(dist) <= threshold) & (cos >= cos_thr)).sum(axis=1)
        i = int(np.argmax(counts))
        if counts[i] > best_count:
            best_count = int(counts[i])
            best = cls.from_batch(h, i)
            needed = _needed_iterations(best_count / len(sp), k, confidence, drawn, needed)
    if best is None:
        return None
    return _support(best, points, threshold)


def _refine_plane(model: PlaneModel, points: Array, threshold: float, rounds: int
                  ) -> PlaneModel:
    """Total least squares on the plane's inliers, re-selected ``rounds`` times.

    A round whose inliers are those of the round before would fit the same points again
    and return the same plane: the rounds stop there.
    """
    fitted = None
    for _ in range(rounds):
        inl = np.abs(model.distance(points)) <= threshold
        if inl.sum() < _MIN_PLANE_POINTS or (fitted is not None and np.array_equal(inl, fitted)):
            break
        model, fitted = fit_plane_svd(take_rows(points, inl)), inl
    return model


def _least_squares(ref: RefinableModel, sub: Array) -> Any:
    """One Levenberg-Marquardt minimisation of the distances of ``sub`` (3, M) [m]."""
    # leastsq evaluates the function and the Jacobian once at x0 to check their
    # shapes before MINPACK evaluates them there again: keep the last of each. MINPACK
    # asks for the Jacobian where it has just evaluated the function: the model there and
    # the points' parts about it (offsets, axial and radial parts) serve both. A vector
    # is recognised by its bytes (x is always a float64 vector of the model's size):
    # equal bytes are equal values, at a fraction of an element-wise comparison's call
    # overhead (a zero of the other sign is only computed again).
    last: dict[str, tuple[bytes, Any]] = {}

    def cached(name: str, compute: Callable[[Array], Any], x: Array) -> Any:
        key = x.tobytes()
        hit = last.get(name)
        if hit is not None and hit[0] == key:
            return hit[1]
        value = compute(x)
        last[name] = (key, value)
        return value

    def at(v: Array) -> tuple[Any, Any]:
        m = ref.from_vector(v)
        return m, m.parts_t(sub)

    def distances(v: Array) -> Array:
        m, parts = cached("m", at, v)
        return m.distance_from(parts)

    def fun(x: Array) -> Array:
        return cached("f", distances, x)

    def jac(x: Array) -> Array:
        return cached("j", lambda v: ref.jacobian_from(v, *cached("m", at, v)), x)

    # Levenberg-Marquardt (MINPACK lmder) with the Jacobian as (P, M) rows
    # (col_deriv) and variables scaled by its column norms, at most MAX_EVALUATIONS
    # function evaluations.
    x, *_ = leastsq(fun, ref.to_vector(), Dfun=jac, full_output=True, col_deriv=True,
                    ftol=_LSQ_TOLERANCE, xtol=_LSQ_TOLERANCE, gtol=_LSQ_TOLERANCE,
                    maxfev=MAX_EVALUATIONS)
    return ref.from_vector(x)


def refine(model: ModelT, points: Array, threshold: float, rounds: int = 2) -> ModelT:
    """Least-squares refinement of a plane, sphere, cylinder or cone on its inliers.

    Geometric point-to-surface distances are minimised (no algebraic bias in the radius);
    a plane gets total least squares.

    Parameters
    ----------
    model : PlaneModel or a :class:`RefinableModel`
    points : (M, 3) float64 array [m]
    threshold : float [m]
        Inliers (|distance| <= threshold) are re-selected before each round.
    rounds : int
        Refinement rounds.
    """
    if isinstance(model, PlaneModel):
        return _refine_plane(model, points, threshold, rounds)
    current: RefinableModel = model
    for _ in range(rounds):
        inl = np.abs(current.distance(points)) <= threshold
        if inl.sum() < current.sample_size + _REFINE_EXTRA_POINTS:
            break
        current = _least_squares(current, np.ascontiguousarray(points[inl].T))  # (3, M)
    return current  # type: ignore[return-value]

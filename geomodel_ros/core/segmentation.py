"""Scene segmentation: raw cloud -> support planes and objects (paper section 3, Figure 1).

1. The cloud is reduced to a voxel grid (the *working cloud*) with normals.
2. Support surfaces (desk, floor, walls) are found first (:mod:`geomodel_ros.core.support`):
   RANSAC planes, with normals, whose connected inlier area exceeds
   ``seg_min_support_area``.
3. The rest is split into objects by local convexity (as in LCCP, Stein et al. 2014):
   smooth patches are joined where most neighbour links across their common border are
   flat or convex (under noise: most of the share that the links inside the patches pass,
   :func:`_surface_pass_rate`), not across a concave crease (object on object, object
   against object),
   a step (parallel faces at different heights) nor a depth jump (occlusion boundary);
   tiny objects are noise; a border whose links show a crease at their median (the
   evidence of the whole border against the noise of that median) is never joined.
   Two further joins
   (:mod:`geomodel_ros.core.joins`) put together the parts of one surface cut by an
   occluder and the inner and outer walls of an open round container; the floor of such a
   container, when it lies in a support's band (a real sensor's band is 10-14 mm thick),
   goes back to it from the support (support points seen through its opening and bounded
   by it, :func:`geomodel_ros.core.joins.contained_floors`).
4. Objects are numbered by size, largest first, after the supports; labels go back to every
   input point through the voxel map, and object points in a support's plane band (the
   contact rims) go to the support.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np
from numpy.typing import NDArray

from geomodel_ros.core.errors import InputError, as_points
from scipy.spatial import Delaunay, QhullError, cKDTree

from geomodel_ros.core.faces import (THREADED_QUERIES, WorkingCloud, estimate_normals,
                                     face_labels, link_folds, neighborhood_moments,
                                     pca_normals, smallest_eigenpairs_sym, voxelize)
from geomodel_ros.core.input import without_far_points
from geomodel_ros.core.geometry import perpendicular_basis
from geomodel_ros.core.fastmath import (MAX_INT16_LABEL, group_by_label, knn_among,
                                        link_components, robust_sigma, rows_finite,
                                        take_rows)
from geomodel_ros.core.noise import K_SUPPORT, NoiseEstimate, disparity_step, resolve_params
from geomodel_ros.core.joins import (contained_floors, join_contained_parts, join_occluded_parts,
                                     join_terraces, merge_patches, own_floors)
from geomodel_ros.core.mixed_pixels import mixed_rows
from geomodel_ros.core.organized import GridCloud, grid_cloud
from geomodel_ros.core.params import ModelingParams
from geomodel_ros.core.ransac import PlaneModel, fit_plane_svd
from geomodel_ros.core.support import (REFIT_MAX_POINTS, SUPPORT_LINK_VOXELS, continued_supports,
                                      support_plane_equation, support_planes)

__all__ = ["DepthNoise", "Segmentation", "segment_scene", "working_noise"]

#: Fewer finite input points than a plane's three make no scene (every label is -1).
MIN_INPUT_POINTS = 3
#: Fewer working points than this make no scene, and a rest of fewer points holds no
#: object: a normal from a neighbourhood of three points is only the plane through them.
MIN_WORKING_POINTS = 4
#: A patch-restricted normal needs this many neighbours in the point's own patch (a plane
#: through fewer, on a voxel grid, is poorly determined).
PATCH_NORMAL_MIN_NEIGHBORS = 6
#: A neighbour that lies above a point's tangent plane by more than this share of
#: ``seg_plane_threshold`` (the noise band of a plane: 1 mm with the defaults, 1.5 mm with
#: config/kinect.yaml) is across a step, not on the same surface: two parallel faces at
#: slightly different heights (a box's top beside a can's top, a cup's rim before the can
#: behind it) or the two sides of a concave crease. On one smooth convex or flat surface
#: every neighbour lies on or below the tangent plane. Measured on the clutter benchmark
#: (20 scenes, ``python -m geomodel_ros.tools.bench_clutter``): 0.25 / 0.5 / 1.0 leave
#: 5.2 / 8.4 / 8.8 % of the objects under-segmented noise-free.
STEP_SHARE = 0.25
#: With a known depth noise (:class:`DepthNoise`) the step at a working point is at least
#: this many times its noise (:func:`working_noise`). One, as the share above is of a plane
#: band of 4 sigma: the step stays at the noise of the surface, so the noisy links it cuts
#: do not close around a piece, while a real Kinect at 1.5-2.5 m (sigma 4-20 mm, depth
#: quantised in terraces) no longer cuts its floor along every terrace. Measured with the
#: frame's noise estimate (``python -m geomodel_ros.tools.bench_clutter``, Kinect noise, 20
#: scenes): 1 sigma leaves 4.0 % of the objects under-segmented, 3 sigma 20.8 % (a step
#: that large no longer parts objects that touch tangentially: whole scenes merge).
STEP_NOISE_SIGMAS = 1.0
#: A border of two patches holds a crease when the median of its links' fold
#: (:func:`_creased_borders`) is concave by more than this many standard errors of that
#: median (the per-link spread measured on the links inside the frame's patches). Three: a
#: one-sided false cut of 0.13 % of the borders of one surface under Gaussian noise (a
#: frame has tens to hundreds of borders); none of 12 seeds of the hand-made borders in
#: ``test/test_segmentation_border_step.py`` is cut without a crease.
BORDER_CREASE_SIGMAS = 3.0
#: The border points of one side of a border lie in a strip about this many point spacings
#: deep (links reach ``seg_max_edge_factor`` = 2.5 voxels across), so the border is about
#: their number over this long, and its votes count once per point spacing along it: the
#: i.i.d. noise of the points dominates a link's statistic, the shared errors of
#: neighbouring normals do not. Measured on a 10 cm border of one plane (50 border points
#: a side, i.i.d. noise plus a shared slow error of twice its size, 100 seeds): the
#: medians' spread implies 27-29 independent votes, this count gives 25.
BORDER_STRIP_POINTS = 2.0
#: The per-link spreads are measured on at most about this many links inside the patches
#: (evenly strided; a Kinect frame holds about 10^5): the relative standard error of a
#: MAD-based sigma is about 1.1 / sqrt(n), 2 % for 4000 links, well below the margin of
#: :data:`BORDER_CREASE_SIGMAS`; all of them cost 5-6 ms a frame.
NULL_LINKS = 4000
#: The share of the noisy links inside the patches that pass the border vote
#: (:func:`_surface_pass_rate`) is taken as at least this: below it a link of one smooth
#: surface votes against more often than for its own surface, the votes no longer tell a
#: surface from a crease, and a share relative to it would join on a quarter of the votes.
#: Half: the simple majority of :data:`geomodel_ros.core.joins.JOIN_MIN_CONVEX_SHARE`. On
#: a plane under i.i.d. noise the step test alone (:data:`STEP_NOISE_SIGMAS` = 1 of each
#: end's noise, the difference of two ends' noise being sqrt(2) of it) passes
#: P(|Z| < 1 / sqrt(2)) = 0.52 of the links. Measured: clutter frames (20 scenes) noise-free
#: 1 (no noisy link), Kinect noise 0.53-1 (median 0.66), kinect-real 0.74-0.86 (0.80);
#: osd_learn 0.64-0.86 (0.75); the PCL mug scene 0.69, the office scene 0.87.
MIN_PASS_RATE = 0.5
#: Significance, in standard errors, of the height difference of two levels of one flat
#: patch and of the rise across their border (:func:`_split_levels`), as for a crease
#: (:data:`BORDER_CREASE_SIGMAS`).
LEVEL_SIGMAS = BORDER_CREASE_SIGMAS
#: A flat patch's two levels are two regions: the share of the links between them is at
#: most this share of what levels drawn at random in the same proportions would give.
#: Measured: two half-planes 2.5-4 mm apart under 0-1 mm noise 0.05-0.06 of it, the
#: clutter benchmark's box and can tops 0.02; levels the noise chose on one flat face
#: (2 mm noise) 0.6-0.7, a face and its rounded rim or a bent face 0.14-0.17.
LEVEL_MIXING = 0.1
#: Refinements of a flat patch's two levels (assignment, then the tilted plane's fit).
LEVEL_ITERATIONS = 8
#: Standard error of the median of n Gaussian samples over sigma / sqrt(n): sqrt(pi / 2).
MEDIAN_STANDARD_ERROR = math.sqrt(math.pi / 2.0)
#: A neighbourhood lies on its plane within the noise when its mean squared distance from
#: it is at most this many standard deviations above what independent noise gives
#: (:func:`_planar_within_noise`): three; the noise alone exceeds it in 0.8 % of the
#: points of a plane (chi-square with k - 3 = 13 degrees of freedom for 16 neighbours).
PLANAR_NOISE_SIGMAS = 3.0
#: A working point holds one disparity level when the depths of its input points spread
#: (standard deviation) less than this share of a depth step: two levels mixed in any
#: proportion p spread by sqrt(p (1 - p)) steps, at least 0.19 for one point in 25 of the
#: other level (a working point holds at most a few tens of input points).
LEVEL_SPREAD = 0.1
#: Where the depths are quantised and a working point holds one disparity level
#: (:func:`level_quantum`), its error is the level's, shared by its neighbours on the same
#: terrace: along a border that follows a terrace edge the votes are not independent, and
#: the median fold carries the staircase whole. A link from a tread to the next level
#: seen from a normal tilted by the riser folds by up to about half a depth step: a crease
#: is seen only beyond it. Hand geometry (quantised planes at 1.5-3 m tilted by 0-70 deg,
#: seen by a Kinect, patches split as the segmentation does, 2175 borders): median folds
#: down to -0.49 of the border's mean quantum. The office scene's plane at 2.3-2.8 m was
#: cut along borders of median fold -0.5 to -4.9 mm where a step is 15-20 mm.
QUANTUM_FOLD_STEPS = 0.5
#: Image neighbours of a working point (for the seams of :func:`_occluding_borders`): its
#: nearest points by viewing direction, at most this many working-grid spacings apart as
#: seen from the sensor (spacing / range). 1.5: the 8-neighbourhood of a square grid
#: (diagonal sqrt(2)) with room for the grid's jitter.
SEAM_RADIUS_SPACINGS = 1.5
#: A working point is at its surface's rim when its neighbours' centroid lies this many
#: working-grid spacings from it along the surface (:func:`_rim_points`): a quarter, well
#: below the 0.6 of the second row in from a straight rim, above the centroid's jitter
#: inside a surface.
RIM_OFFSET_SPACINGS = 0.25
#: Image neighbours looked at per working point: its own surface's 8-neighbourhood and
#: itself take 9, and a surface behind it across an outline is denser in viewing angle
#: (farther), so 16 reach past the own surface's ring to the next one (a 5 x 5 block has 25).
SEAM_NEIGHBORS = 16
#: The image-neighbour search stops this share beyond the widest angle a pair can be
#: kept at (:func:`_image_seam`): far above the rounding of that bound's arithmetic
#: (about 1e-16), far below any difference of angles that matters.
SEAM_BOUND_MARGIN = 1e-6
#: A patch border is an outline in front of the other patch when more than this share of
#: its image seam are depth jumps longer than a link: the two surfaces meet in 3-D only
#: along a minority of the seam, and the convexity votes of those few links say nothing
#: about a surface continuing into the other. Half: a majority of the seam.
SEAM_JUMP_SHARE = 0.5
#: The support around an object point near a support plane (its local height) is that in
#: the cells of the plane up to this many from the point's own, cells of one link of the
#: support's pieces (``SUPPORT_LINK_VOXELS`` working voxels): 2-3 links to every side,
#: beyond a contact rim (a neighbourhood wide) and a wall's foot within the support band.
SUPPORT_AROUND_CELLS = 2
#: ... or, where those hold none of the support, the first of twice, four times ... as
#: many that holds some, up to this many (16 links: 6-16 cm at 4-10 mm working voxels).
SUPPORT_AROUND_MAX_CELLS = 16
#: At most this many cells per support plane; a larger plane (a room's floor) gets cells
#: twice as large until it fits.
AROUND_MAX_CELLS = 1 << 22

#: Share of a patch's normals, among those between its two normal clusters' means, that
#: lie in the middle half between them: a surface that turns steadily (a can's side, a
#: sphere) puts half of them there, two faces met at a fold only the strip that rounds the
#: fold; a patch at most half as full there as a steady turn is two faces
#: (:func:`_split_folds`).
FOLD_MIDDLE_SHARE = 0.25
#: Normal-refinement passes of the two clusters of a patch's normals (2-means from the
#: split along their widest spread; it settles within a few).
FOLD_ITERATIONS = 5
#: Norm below which two unit normal means count as one direction (no great circle).
_FOLD_TINY = 1e-12


class DepthNoise(Protocol):
    """Depth noise of a sensor as a function of range (e.g. a frame's noise estimate)."""

    def sigma(self, z: NDArray[np.float64]) -> NDArray[np.float64]:
        """Return the noise sigma [m] along the ray at ranges ``z`` (M,) [m]."""


@dataclass
class Segmentation:
    """Result of :func:`segment_scene`.

    Attributes
    ----------
    labels : (N,) int64
        Object id of every input point (row of the input), -1 for invalid points and noise.
    support_ids : list[int]
        Ids of the support planes (desk, floor, walls), which come first.
    support_planes : dict[int, (normal (3,), d)]
        Plane n . x + d = 0 of each support, normal towards the sensor.
    timing : dict[str, float]
        Seconds per stage.
    noise : NoiseEstimate or None
        The frame's noise (None with ``noise_model = fixed``).
    """

    labels: NDArray[np.int64]
    support_ids: list[int] = field(default_factory=list)
    timing: dict[str, float] = field(default_factory=dict)
    support_planes: dict[int, tuple[NDArray[np.float64], float]] = field(default_factory=dict)
    noise: NoiseEstimate | None = None

    @property
    def object_ids(self) -> NDArray[np.int64]:
        ids = np.unique(self.labels)
        return ids[ids >= 0]


def segment_scene(points: NDArray, params: ModelingParams | None = None, *,
                  rng: np.random.Generator | int | None = None,
                  noise: NoiseEstimate | None = None,
                  organized_shape: tuple[int, int] | None = None) -> Segmentation:
    """Segment a scene cloud into support planes and objects.

    Parameters
    ----------
    points : (N, 3) or (H, W, 3) float array [m]
        Scene cloud in the sensor frame; non-finite points (NaN for invalid pixels of an
        organized cloud) are allowed and get label -1.
    params : ModelingParams, optional
        ``seg_*`` parameters are used.
    rng : Generator, seed or None
        Randomness for the plane RANSAC; defaults to ``params.seed``.
    noise : NoiseEstimate, optional
        The frame's noise when known; with ``noise_model = auto`` the ``seg_*`` tolerances
        follow it (:func:`geomodel_ros.core.noise.resolve_params`), and so do the step
        between two surfaces (at least the noise of the working points,
        :func:`working_noise`) and the normals at patch borders (from the point's own
        patch only where its neighbourhood lies off its plane by more than that noise: a
        crease). With ``noise_model = fixed`` the step is ``STEP_SHARE *
        seg_plane_threshold`` everywhere and every such point takes its own patch's normal.
    organized_shape : (H, W), optional
        Image shape of (N, 3) ``points`` that are the row-major pixels of an organized
        cloud ((H, W, 3) ``points`` give it themselves). With ``organized_fast_path`` the
        working cloud, its neighbours and normals then come from the image grid
        (:mod:`geomodel_ros.core.organized`) instead of a voxel grid and kNN searches.

    Returns
    -------
    Segmentation with labels aligned with the input rows (row-major for organized input).

    Raises
    ------
    InputError
        For malformed points, or an ``organized_shape`` whose H * W is not N.
    """
    t0 = time.perf_counter()
    params = params if params is not None else ModelingParams()
    shape = organized_shape if np.ndim(points) != 3 else np.shape(points)[:2]
    pts = as_points(points, allow_organized=True)
    if shape is not None and shape[0] * shape[1] != len(pts):
        raise InputError(f"organized_shape {tuple(shape)} does not match {len(pts)} points")
    pts = without_far_points(pts, params)
    configured_band = params.seg_plane_threshold
    params, noise = resolve_params(pts, params, noise=noise)
    rng = np.random.default_rng(params.seed if rng is None else rng)
    labels = np.full(len(pts), -1, dtype=np.int64)
    finite = np.flatnonzero(rows_finite(pts))
    timing: dict[str, float] = {}
    if len(finite) < MIN_INPUT_POINTS:
        timing["segmentation_s"] = time.perf_counter() - t0
        return Segmentation(labels, [], timing, noise=noise)
    p = take_rows(pts, finite)
    step = disparity_step(p)
    if shape is not None and params.mixed_pixel_filter:
        finite = finite[~mixed_rows(pts, shape, finite, params, noise, step)]
        p = take_rows(pts, finite)
    grid = grid_cloud(pts, shape, finite, params) \
        if shape is not None and params.organized_fast_path else None
    wp, inverse, counts = voxelize(p, params.seg_voxel_size) if grid is None else \
        (grid.points, grid.inverse, grid.counts)
    if len(wp) < MIN_WORKING_POINTS:
        timing["segmentation_s"] = time.perf_counter() - t0
        return Segmentation(labels, [], timing, noise=noise)
    wn, _, nbrs, sqdist = estimate_normals(wp, params.normal_neighbors, return_sqdist=True) \
        if grid is None else (grid.normals, grid.variation, grid.neighbors, grid.sqdist)
    t1 = time.perf_counter()
    timing["seg_normals_s"] = t1 - t0
    supports = support_planes(wp, wn, nbrs, sqdist, params, rng, noise)
    t2 = time.perf_counter()
    timing["seg_supports_s"] = t2 - t1
    quantum = level_quantum(p, inverse, counts, step, params.seg_voxel_size)
    floors = np.zeros(len(wp), dtype=bool)
    own_labels = _working_labels(wp, wn, counts, supports, params, grid, noise, step, quantum,
                                 None if grid is not None else (nbrs, sqdist),
                                 (nbrs, sqdist), floors)[inverse]
    planes = _claim_contact_rims(
        p, own_labels, len(supports), params, rng,
        None if noise is None or noise.samples == 0 else
        LocalSupport(wp, inverse, counts, noise, quantum, configured_band,
                     SUPPORT_LINK_VOXELS * params.seg_voxel_size), floors[inverse])
    _drop_small_objects(own_labels, len(supports), params.seg_min_cluster_points)
    labels[finite] = own_labels
    timing["seg_objects_s"] = time.perf_counter() - t2
    timing["segmentation_s"] = time.perf_counter() - t0
    return Segmentation(labels, list(range(len(supports))), timing, planes, noise)


def _working_labels(wp: NDArray[np.float64], wn: NDArray[np.float64], counts: NDArray[np.int64],
                    supports: list[NDArray[np.int64]], params: ModelingParams,
                    grid: GridCloud | None = None, noise: DepthNoise | None = None,
                    step: float | None = None, quantum: NDArray[np.float64] | None = None,
                    near: tuple[NDArray[np.int64], NDArray[np.float64]] | None = None,
                    links: tuple[NDArray[np.int64], NDArray[np.float64]] | None = None,
                    floors: NDArray[np.bool_] | None = None) -> NDArray[np.int64]:
    """Label of every working point: supports 0 .. S-1, objects S, S+1, ... by size, -1 noise.

    Parameters
    ----------
    wp, wn : (M, 3) float64 arrays
        Working cloud [m] and its unit normals.
    counts : (M,) int64 array
        Input points per working point.
    supports : list of int64 arrays
        Working-point indices of each support plane (a container's floor leaves its
        support's array, in place: :func:`_return_floors`).
    params : ModelingParams
    grid : GridCloud, optional
        The organized working cloud ``wp`` comes from (its neighbours are reused).
    noise : DepthNoise, optional
        Depth noise of the working points (:func:`working_noise`).
    step : float, optional
        The frame's disparity step in 1/z [1/m] (:func:`disparity_step`; None when its
        depths are not quantised): far terraces of one plane are joined.
    quantum : (M,) float64 array, optional
        Depth quantisation [m] left in every working point (:func:`level_quantum`).
    near : (neighbors, sqdist), optional
        The (M, k) nearest neighbours of every working point and their squared distances
        [m^2] (voxel path): the objects' neighbours among the points of no support are
        taken from them where they can be (:func:`_rest_neighbourhood`).
    links : (neighbors, sqdist), optional
        The same for either path: with them (and ``seg_join_contained``) the floor of an
        open container that a support took goes back to the container
        (:func:`geomodel_ros.core.joins.contained_floors`).
    floors : (M,) bool array, optional
        Set in place where a working point is such a floor, or the floor of an open
        container that stayed in the container's segment
        (:func:`geomodel_ros.core.joins.own_floors`; either way, in the support's band,
        no support may claim it).

    Returns
    -------
    (M,) int64 array
    """
    wlabel = np.full(len(wp), -1, dtype=np.int64)
    for sid, sel in enumerate(supports):
        wlabel[sel] = sid
    comp, comp_ok, patches = _object_segments(wp, counts, wlabel < 0, params, grid, noise,
                                              quantum, near)
    # A container's parts (inner and outer wall, a floor inside) are joined first: a
    # container's own wall in front of its floor is then no occluder of that floor.
    contained = params.seg_join_contained and bool(supports)
    if contained:
        first = fit_plane_svd(take_rows(wp, supports[0]))
        comp = join_contained_parts(wp, wn, comp, comp_ok, first, noise, patches,
                                    (params.seg_max_edge_factor * params.seg_voxel_size,
                                     params.seg_plane_threshold + params.seg_voxel_size))
    if params.seg_max_occlusion_gap > 0:
        comp = join_occluded_parts(wp, wn, comp, comp_ok, params)
    comp = join_terraces(wp, comp, comp_ok, step, params, noise)
    if contained:
        if links is not None:
            taken = _return_floors(wp, wn, comp, comp_ok, wlabel, supports, params, links,
                                   noise, first)
            if floors is not None:
                floors[taken] = True
        if floors is not None:
            stand = params.seg_plane_threshold + params.seg_voxel_size
            for sid, sel in enumerate(supports):
                plane = first if sid == 0 else fit_plane_svd(take_rows(wp, sel))
                floors[own_floors(wp, wn, comp, comp_ok, plane, stand, noise)] = True
    if supports and links is not None:
        continued_supports(wp, counts, comp, comp_ok, wlabel, supports, links,
                           SUPPORT_LINK_VOXELS * params.seg_voxel_size, noise, params)
    wlabel[comp_ok] = len(supports) + _size_ranks(comp[comp_ok], counts[comp_ok])
    return wlabel


def _return_floors(wp: NDArray[np.float64], wn: NDArray[np.float64], comp: NDArray[np.int64],
                   comp_ok: NDArray[np.bool_], wlabel: NDArray[np.int64],
                   supports: list[NDArray[np.int64]], params: ModelingParams,
                   links: tuple[NDArray[np.int64], NDArray[np.float64]],
                   noise: DepthNoise | None, first: PlaneModel | None = None
                   ) -> NDArray[np.int64]:
    """Give the floors of open containers that the supports took back to the containers.

    In place, and return their working points: the points that
    :func:`geomodel_ros.core.joins.contained_floors` finds leave their support
    (``supports``, ``wlabel`` set to -1) and join their container's segment (``comp``,
    ``comp_ok``). An object stands on a support when its lowest working point
    lies within the support's band plus one voxel (a working point is the centroid of its
    voxel's points). Supports are visited in order, the objects as the earlier ones left
    them. ``first``: the least-squares plane of the first support's working points when
    already fitted (they are the same points here: the first support is visited first).
    """
    in_support = wlabel >= 0
    stand = params.seg_plane_threshold + params.seg_voxel_size
    link = SUPPORT_LINK_VOXELS * params.seg_voxel_size
    every = []
    for sid, sel in enumerate(supports):
        plane = first if sid == 0 and first is not None else fit_plane_svd(take_rows(wp, sel))
        taken, owner = contained_floors(wp, wn, comp, comp_ok, sel, plane, in_support,
                                        *links, link, stand, noise)
        if len(taken):
            comp[taken], comp_ok[taken] = owner, True
            wlabel[taken], in_support[taken] = -1, False
            supports[sid] = np.setdiff1d(sel, taken, assume_unique=True)
            every.append(taken)
    return np.concatenate(every) if every else np.zeros(0, dtype=np.int64)


def _object_segments(wp: NDArray[np.float64], counts: NDArray[np.int64],
                     free: NDArray[np.bool_], params: ModelingParams,
                     grid: GridCloud | None = None, noise: DepthNoise | None = None,
                     quantum: NDArray[np.float64] | None = None,
                     near: tuple[NDArray[np.int64], NDArray[np.float64]] | None = None
                     ) -> tuple[NDArray[np.int64], NDArray[np.bool_],
                                tuple[NDArray[np.int64],
                                      Callable[[NDArray[np.int64]], NDArray[np.bool_]]]]:
    """Convex objects among the ``free`` (M,) working points (not in a support).

    With the organized ``grid`` of ``wp`` the free points' normals come from its neighbour
    lists (:meth:`GridCloud.restricted`) instead of a kNN search among them; with ``near``
    (the (M, k) neighbours of all working points and their squared distances) the search
    is only for the free points that it does not answer (:func:`_rest_neighbourhood`).
    ``noise`` is the depth noise (:func:`working_noise`), ``quantum`` (M,) the depth
    quantisation [m] left in each working point (:func:`level_quantum`).

    Returns
    -------
    comp : (M,) int64 array
        Object id of every free working point, -1 elsewhere.
    comp_ok : (M,) bool array
        Points of the objects with at least ``seg_min_cluster_points`` input points (the
        smaller ones are noise).
    patches : (labels, concave)
        Smooth patch of every free working point (-1 elsewhere) and the test that tells
        which patches are concave (:func:`_convex_objects`; none concave without free
        points).
    """
    rest_idx = np.flatnonzero(free)
    comp = np.full(len(wp), -1, dtype=np.int64)
    labels = np.full(len(wp), -1, dtype=np.int64)
    concave = _none_concave
    if len(rest_idx) >= MIN_WORKING_POINTS:
        # Normals recomputed without the supports, so they do not blend into the desk.
        comp[rest_idx], labels[rest_idx], concave = _convex_objects(
            take_rows(wp, rest_idx), counts[rest_idx], params, noise,
            None if grid is None else grid.restricted(rest_idx),
            None if quantum is None else quantum[rest_idx],
            None if near is None or grid is not None else
            _rest_neighbourhood(wp, rest_idx, *near, params.normal_neighbors))
    rest = comp >= 0
    size = np.bincount(comp[rest], weights=counts[rest], minlength=int(comp.max()) + 1)
    comp_ok = rest.copy()
    comp_ok[rest] = (size >= params.seg_min_cluster_points)[comp[rest]]
    return comp, comp_ok, (labels, concave)


def _none_concave(which: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Return no patch concave (the test of :func:`_object_segments` without patches)."""
    return np.zeros(int(which.max(initial=-1)) + 1, dtype=bool)


def _size_ranks(comp: NDArray[np.int64], counts: NDArray[np.int64]) -> NDArray[np.int64]:
    """Rank of each point's object by its size in input points, largest first (0 ..).

    Ties keep the order of the object ids, so the numbering is stable.
    """
    uniq, compact = np.unique(comp, return_inverse=True)
    sizes = np.bincount(compact.ravel(), weights=counts, minlength=len(uniq))
    rank = np.empty(len(uniq), dtype=np.int64)
    rank[np.argsort(-sizes, kind="stable")] = np.arange(len(uniq))
    return rank[compact.ravel()]


@dataclass
class LocalSupport:
    """What :func:`_claim_contact_rims` needs to judge object points against the local support.

    Attributes
    ----------
    points : (M, 3) float64 array
        Working points [m], sensor at the origin.
    inverse : (F,) int64 array
        Working point of every finite input point.
    counts : (M,) int64 array
        Input points per working point.
    noise : NoiseEstimate
        The frame's noise (its ``scale`` is the share of it that neighbours hold in common).
    quantum : (M,) float64 array
        Depth quantisation [m] left in every working point (:func:`level_quantum`).
    floor : float
        Narrowest band [m] (the configured ``seg_plane_threshold``).
    cell : float
        Edge [m] of the square cells of a support plane in which the support around a
        point is gathered (:func:`_support_around`).
    """

    points: NDArray[np.float64]
    inverse: NDArray[np.int64]
    counts: NDArray[np.int64]
    noise: NoiseEstimate
    quantum: NDArray[np.float64]
    floor: float
    cell: float


def _claim_contact_rims(p: NDArray[np.float64], labels: NDArray[np.int64], n_supports: int,
                        params: ModelingParams, rng: np.random.Generator,
                        local: LocalSupport | None = None,
                        floors: NDArray[np.bool_] | None = None
                        ) -> dict[int, tuple[NDArray[np.float64], float]]:
    """Refit each support's plane and give it the object points in its plane band.

    The voxel normals at a contact blend desk and object, so the contact rim may have
    joined the object. Each support's plane is refit on its own input points (at most
    :data:`geomodel_ros.core.support.REFIT_MAX_POINTS`, drawn with ``rng``); object points
    within ``seg_plane_threshold`` of it are relabelled to the support, in place in
    ``labels`` (F,) (the labels of the points ``p`` (F, 3) [m]). With the frame's
    noise known (``local``), only those whose working point lies on the support as seen
    around it (:func:`_on_local_support`): the band holds a single noisy point of the
    support (four sigma of the noise along the normal, the frame's slowly varying error
    included), so under a real sensor's noise it reaches 10-14 mm up every object's wall
    (kinect-real clutter: a cone, cup or bowl lost 20-36 % of its points to the desk).
    The points ``floors`` (F,) (a container's floor seen through its opening, taken back
    from a support by :func:`_return_floors` or kept by the container itself,
    :func:`geomodel_ros.core.joins.own_floors`) are never claimed.

    Returns
    -------
    dict[int, (normal (3,), d)]
        Plane of each support, normal towards the sensor.
    """
    planes: dict[int, tuple[NDArray[np.float64], float]] = {}
    if local is not None:  # the label of every working point (shared by its points)
        working = np.full(len(local.counts), -1, dtype=np.int64)
        working[local.inverse] = labels
    obj = np.flatnonzero((labels >= n_supports) if floors is None else
                         (labels >= n_supports) & ~floors)
    obj_pts = take_rows(p, obj)
    for sid in range(n_supports):
        own = np.flatnonzero(labels == sid)
        if len(own) > REFIT_MAX_POINTS:
            own = rng.choice(own, REFIT_MAX_POINTS, replace=False)
        nrm, d = planes[sid] = support_plane_equation(take_rows(p, own), params)
        band = np.abs(obj_pts @ nrm + d) <= params.seg_plane_threshold
        near = obj[band]
        if local is not None and len(near):
            band[band] = _on_local_support(p, working == sid, near, nrm, d, local)
            near = obj[band]
        labels[near] = sid
        if sid + 1 < n_supports:  # a claimed point is no longer an object's
            obj, obj_pts = obj[~band], take_rows(obj_pts, ~band)
    return planes


def _drop_small_objects(labels: NDArray[np.int64], n_supports: int, min_points: int) -> None:
    """Label -1, in place, the objects left with fewer than ``min_points`` input points.

    Objects are kept from ``seg_min_cluster_points`` input points on when the working
    points are clustered; the contact rims the supports then claim
    (:func:`_claim_contact_rims`) can leave less of one: a desk piece whose points mostly
    lay in the desk's band, reported as a plane of a few centimetres (kinect-real clutter:
    4 planes of 64-105 points in 60 scenes). What is left is noise, as a cluster of that
    size is.
    """
    obj = np.flatnonzero(labels >= n_supports)
    own = labels[obj]
    labels[obj[np.bincount(own)[own] < min_points]] = -1


def _on_local_support(p: NDArray[np.float64], support: NDArray[np.bool_],
                      near: NDArray[np.int64], normal: NDArray[np.float64], d: float,
                      local: LocalSupport) -> NDArray[np.bool_]:
    """Tell which object points ``near`` a support's plane lie on the support around them.

    The candidates of one working point are averaged, so their height above the plane is
    known to the noise of that mean, not of a single point; and the frame's slowly varying
    error, which a whole-plane band must hold, is shared by the support's points next to
    them. So their mean height is taken over the mean height of the support's input
    points around the working point (:func:`_support_around`, cells of one link of the
    support's pieces, ``local.cell``), and they lie on the support where that lift is at
    most K_SUPPORT (the support band's sigmas) times the noise of the difference of the
    two means (the independent part of the noise, sigma / ``scale``, along the normal at
    the plane's incidence), plus the depth quantum left in the working point, and never
    less than ``local.floor``. A point below the local support (a negative lift) is on it.
    Where no support is seen around a working point (a piece of a far floor cut off from
    it, parted by the quantised depth), the plane's band is all there is to judge by, and
    it decides as before.

    Parameters
    ----------
    p : (F, 3) float64 array
        Finite input points [m].
    support : (M,) bool array
        The support's working points.
    near : (C,) int64 array
        Object points (rows of ``p``) within the support's band.
    normal, d : (3,) float64 array, float
        The support's plane, normal towards the sensor.
    local : LocalSupport

    Returns
    -------
    (C,) bool array
    """
    inverse, counts = local.inverse, local.counts
    # The candidates of one working point, averaged: a working point at the contact also
    # holds wall points above the band, which are not in question.
    cand, at = np.unique(inverse[near], return_inverse=True)
    n_cand = np.bincount(at, minlength=len(cand))
    mean = np.bincount(at, weights=take_rows(p, near) @ normal + d,
                       minlength=len(cand)) / n_cand
    n_ref, sum_ref = _support_around(local.points, np.where(support, counts, 0),
                                     take_rows(local.points, cand), normal, d, local.cell)
    seen = n_ref > 0
    noise = local.noise
    sigma = noise.sigma(np.linalg.norm(local.points[cand], axis=1)) / noise.scale \
        * noise.plane_cos
    band = np.maximum(local.floor, K_SUPPORT * sigma * np.sqrt(
        1.0 / n_cand + 1.0 / np.maximum(n_ref, 1))) + local.quantum[cand]
    lift = mean - sum_ref / np.maximum(n_ref, 1)
    return (~seen | (lift <= band))[at]


def _support_around(points: NDArray[np.float64], weights: NDArray[np.int64],
                    at: NDArray[np.float64], normal: NDArray[np.float64], d: float,
                    cell: float) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Count a support's input points around each of the points ``at`` and sum their heights.

    The plane (normal, d) is cut into square cells of ``cell`` [m]; around a point are the
    cells up to :data:`SUPPORT_AROUND_CELLS` from its own along either axis, or, where
    they hold none of the support (its foot hidden under a flared wall), up to twice,
    four times ... as many, at most :data:`SUPPORT_AROUND_MAX_CELLS`: the nearest of the
    support. ``points`` (M, 3) [m] are the working points, ``weights`` (M,) the support's
    input points in each (0 off the support); a working point is the mean of its input
    points, so its height times its count is the sum of theirs.

    Returns
    -------
    n : (C,) int64 array
        Support input points around each of ``at`` (C, 3).
    total : (C,) float64 array [m]
        The sum of their heights above the plane.
    """
    c = len(at)
    sup = np.flatnonzero(weights)
    if not len(sup) or not c:
        return np.zeros(c, dtype=np.int64), np.zeros(c)
    sp = take_rows(points, sup)
    e1, e2 = perpendicular_basis(normal)
    # The support's coordinates along the plane as two vectors: a reduction over the
    # first axis of an (S, 2) array is several times slower than over a contiguous vector.
    own = (sp @ e1, sp @ e2)
    ask = np.c_[at @ e1, at @ e2]
    low = np.minimum([own[0].min(), own[1].min()], ask.min(axis=0))
    span = np.maximum([own[0].max(), own[1].max()], ask.max(axis=0)) - low
    while np.prod(span / cell + 1.0) > AROUND_MAX_CELLS:  # a room: coarser cells
        cell *= 2.0
    ou, ov = (np.floor((o - lo) / cell).astype(np.int64) for o, lo in zip(own, low))
    ask = np.floor((ask - low) / cell).astype(np.int64)
    shape = np.maximum([ou.max(), ov.max()], ask.max(axis=0)) + 1
    flat = ou * shape[1] + ov
    w = weights[sup]
    grids = [np.bincount(flat, weights=v, minlength=int(np.prod(shape))).reshape(shape)
             for v in (w, w * (sp @ normal + d))]
    tables = []
    for g in grids:  # box sums from summed-area tables
        table = np.zeros((shape[0] + 1, shape[1] + 1))
        table[1:, 1:] = g.cumsum(axis=0).cumsum(axis=1)
        tables.append(table)
    n, total = np.zeros(c), np.zeros(c)
    rows = np.arange(c)
    r = SUPPORT_AROUND_CELLS
    while len(rows) and r <= SUPPORT_AROUND_MAX_CELLS:
        u0, v0 = np.clip(ask[rows] - r, 0, shape).T
        u1, v1 = np.clip(ask[rows] + r + 1, 0, shape).T
        n[rows], total[rows] = (t[u1, v1] - t[u0, v1] - t[u1, v0] + t[u0, v0] for t in tables)
        rows = rows[n[rows] < 0.5]
        r *= 2
    return np.rint(n).astype(np.int64), total


def working_noise(points: NDArray[np.float64], counts: NDArray[np.int64],
                  noise: DepthNoise | None = None) -> NDArray[np.float64]:
    """Depth noise [m] of every working point: sigma at its range over sqrt(count).

    Parameters
    ----------
    points : (M, 3) float64 array [m]
        Working points, sensor at the origin.
    counts : (M,) int64 array
        Input points averaged into each working point.
    noise : DepthNoise, optional
        The sensor's depth noise; without it every value is 0 (noise unknown).

    Returns
    -------
    (M,) float64 array [m]
    """
    if noise is None:
        return np.zeros(len(points))
    sigma = np.asarray(noise.sigma(np.linalg.norm(points, axis=1)), dtype=np.float64)
    return sigma / np.sqrt(np.maximum(counts, 1))


def _rest_neighbourhood(wp: NDArray[np.float64], rest_idx: NDArray[np.int64],
                        nbrs: NDArray[np.int64], sqdist: NDArray[np.float64], k: int
                        ) -> tuple[NDArray, ...]:
    """Estimate the normals of the working points ``rest_idx`` from their ``k`` nearest.

    The result of :func:`geomodel_ros.core.faces.estimate_normals` on ``wp[rest_idx]``
    (equal distances aside), from the neighbours ``nbrs`` (M, K) and squared distances
    ``sqdist`` [m^2] of all working points ``wp`` (M, 3) [m]: most points of no support
    have no support point among their nearest (:func:`geomodel_ros.core.fastmath.knn_among`);
    only the others are searched again.

    Returns
    -------
    normals (R, 3), variation (R,), neighbors (R, k'), sqdist (R, k')
        As :func:`geomodel_ros.core.faces.estimate_normals` returns them (k' = min(k, R);
        indices into ``rest_idx``).
    off_plane : (R,) float64 array [m^2]
        Mean squared distance of each neighbourhood from its plane (its covariance's
        smallest eigenvalue, :func:`geomodel_ros.core.faces.pca_normals`).
    """
    rest = take_rows(wp, rest_idx)
    near, near_sq = knn_among(wp, rest_idx, nbrs, sqdist, k)
    normals, variation, off_plane = pca_normals(rest, near)
    return normals, variation, near, near_sq, off_plane


def _convex_objects(points: NDArray[np.float64], counts: NDArray[np.int64],
                    params: ModelingParams, noise: DepthNoise | None = None,
                    neighbourhood: tuple[NDArray, ...] | None = None,
                    quantum: NDArray[np.float64] | None = None,
                    own: tuple[NDArray, ...] | None = None
                    ) -> tuple[NDArray[np.int64], NDArray[np.int64],
                               Callable[[NDArray[np.int64]], NDArray[np.bool_]]]:
    """Object label of every point of a support-free working cloud (local convexity).

    Parameters
    ----------
    points : (M, 3) float64 array [m]
        Working points that are in no support.
    counts : (M,) int64 array
        Input points per working point.
    params : ModelingParams
    noise : DepthNoise, optional
        Depth noise of the working points (:func:`working_noise`).
    neighbourhood : (normals, variation, neighbors, sqdist), optional
        The points' normals, surface variation and neighbour lists when known (organized
        path); by default they are estimated over the ``normal_neighbors`` nearest points
        (given as ``own``, the same from :func:`_rest_neighbourhood`, when known, followed
        by each neighbourhood's mean squared distance from its plane).

    Returns
    -------
    objects : (M,) int64 array
        Object id 0 .. K-1 of every point.
    patches : (M,) int64 array
        Smooth patch 0 .. P-1 of every point (the objects are groups of them).
    concave : callable
        Given patch ids (Q,), tell which patches are concave as seen from the sensor
        ((P,) bool array, :func:`_concave_patches`: a container's inside). An object may
        hold such a patch together with patches of another object (the inner wall of a cup
        against a can behind it, the two meeting smoothly at the cup's rim); the container
        join judges it on its own (:func:`geomodel_ros.core.joins.join_contained_parts`).

    Notes
    -----
    Patches are smooth regions (:func:`geomodel_ros.core.faces.face_labels`); they are
    grouped into objects from their border votes (:func:`_border_votes`,
    :func:`geomodel_ros.core.joins.merge_patches`). With the frame's noise known, a border
    seen mostly as one patch's outline in front of the other (:func:`_occluding_borders`)
    is a crease whatever its votes.
    """
    m = len(points)
    # ``own`` also holds the neighbourhoods' squared distances from their planes.
    normals, variation, nbrs, sqdist, *off_plane = neighbourhood if neighbourhood is not None \
        else own if own is not None else \
        estimate_normals(points, params.normal_neighbors, return_sqdist=True)
    noise_w = working_noise(points, counts, noise)
    if noise is not None and not off_plane:
        off_plane = [smallest_eigenpairs_sym(*neighborhood_moments(points, nbrs))[0]]
    cloud = WorkingCloud(points, normals, variation, nbrs, np.ones(m, dtype=np.int64),
                         np.arange(m), sqdist)
    max_edge = params.seg_max_edge_factor * params.seg_voxel_size
    planar = None if noise is None else \
        _planar_within_noise(off_plane[0], noise_w / getattr(noise, "scale", 1.0), nbrs)
    patches = face_labels(cloud, params.face_angle_threshold, params.edge_variation_threshold,
                          params.min_face_points, max_edge,
                          None if neighbourhood is None else params.seg_voxel_size,
                          planar=planar)
    floor = STEP_SHARE * params.seg_plane_threshold
    step = np.maximum(floor, STEP_NOISE_SIGMAS * noise_w)
    parallel = float(np.cos(params.face_angle_threshold))
    patches = _cut_steps(points, normals, nbrs, sqdist, patches, max_edge, step,
                         min_piece=params.min_face_points,
                         noisy=STEP_NOISE_SIGMAS * noise_w > floor, parallel_cos=parallel)
    stepped: list[tuple[int, int]] = []
    surfaces = patches  # the pass rate is that of the smooth patches as grown
    if noise is not None:
        patches, stepped = _split_levels(points, normals, nbrs, sqdist, patches, max_edge,
                                         noise_w, floor, params.min_face_points,
                                         params.face_angle_threshold)
    if noise is not None:  # two faces grown into one patch across a fold in small turns
        patches = _split_folds(points, normals, nbrs, sqdist, patches, max_edge, noise_w,
                               params.min_face_points, params.face_angle_threshold)
    n_p = int(patches.max()) + 1
    # Points smooth only by the noise test sit where the noise or an edge raised their
    # variation: next to a patch border their normals are refitted from their own patch.
    normals = _patch_normals(points, normals, nbrs, patches, noise_w, *off_plane,
                             refit=None if planar is None else
                             planar & (variation > params.edge_variation_threshold))
    a, b, votes, yes, creased = _border_votes(
        points, normals, nbrs, sqdist, patches, n_p, max_edge,
        params.seg_concavity_tolerance, step, parallel,
        whole=None if noise is None else (noise_w,
                                          np.zeros(m) if quantum is None else quantum),
        crease_angle=params.face_angle_threshold)
    if noise is not None:  # an outline's jump is judged against the noise
        creased = creased | _outlines(points, normals, nbrs, sqdist, patches, a, b, params,
                                      noise_w / getattr(noise, "scale", 1.0), quantum)
    if stepped and creased is not None:  # a split patch's two levels meet at a step
        creased |= np.isin(a * n_p + b, [min(x, y) * n_p + max(x, y) for x, y in stepped])
    obj = merge_patches(n_p, a, b, votes, yes, sizes=np.bincount(patches, minlength=n_p),
                        exact=None if noise is None else
                        np.bincount(patches[step > floor], minlength=n_p) == 0,
                        creased=creased,
                        pass_rate=1.0 if noise is None else _surface_pass_rate(
                            points, normals, nbrs, sqdist, surfaces, max_edge,
                            params.seg_concavity_tolerance, step, step > floor, parallel))
    return obj[patches].astype(np.int64), patches, \
        lambda which: _concave_patches(points, normals, nbrs, sqdist, patches, n_p, max_edge,
                                       which)


def _fold_sides(normals: NDArray[np.float64]
                ) -> tuple[NDArray[np.bool_], float, float, NDArray[np.bool_]]:
    """Split a patch's unit normals (N, 3) into two clusters.

    Returns side (N,) bool, angle, middle and core (N,) bool. The clusters start from the
    split along the normals' widest spread and are refined as spherical 2-means
    (:data:`FOLD_ITERATIONS`). ``angle`` [rad] is that between the two means; along the
    great circle through them, ``middle`` is the share of the normals between the means
    that lie in the middle half (:data:`FOLD_MIDDLE_SHARE`), and ``core`` marks the normals
    outside that half (those of the faces, not of the strip that rounds a fold).
    """
    mu = normals.mean(axis=0)
    d = normals - mu
    _, vec = np.linalg.eigh(d.T @ d)
    side = d @ vec[:, 2] > 0.0
    c = np.zeros((2, 3))
    for _ in range(FOLD_ITERATIONS):
        if side.all() or not side.any():
            return side, 0.0, 1.0, side
        c[0] = normals[~side].sum(axis=0)
        c[1] = normals[side].sum(axis=0)
        c /= np.linalg.norm(c, axis=1, keepdims=True)
        side = normals @ c[1] > normals @ c[0]
    cos = float(np.clip(c[0] @ c[1], -1.0, 1.0))
    e1 = c[1] - cos * c[0]
    norm = float(np.linalg.norm(e1))
    # The angle from its sine and cosine: acos(cos) is 0 for angles below ~1.5e-8 rad,
    # where the cosine rounds to 1, although the means still span a great circle.
    angle = math.atan2(norm, cos)
    if norm < _FOLD_TINY or side.all() or not side.any():
        return side, angle, 1.0, side
    t = np.arctan2(normals @ (e1 / norm), normals @ c[0]) / angle
    between = np.count_nonzero((t >= 0.0) & (t <= 1.0))
    mid = (t > 0.25) & (t < 0.75)
    return side, angle, np.count_nonzero(mid) / max(between, 1), ~mid


def _planar_face(points: NDArray[np.float64], noise: NDArray[np.float64]) -> bool:
    """Tell whether points (N, 3) lie on their best plane within their noise (N,) [m].

    The bound is that of :func:`_planar_within_noise` for one neighbourhood of N points:
    the mean square off the plane of N points with independent noise and no shape is
    (N - 3) / N of their mean variance, :data:`PLANAR_NOISE_SIGMAS` standard deviations
    above that the most the noise gives. The noise is the frame's whole noise (the part
    neighbours share too: over a face it shows as well).
    """
    n = len(points)
    if n < 4:
        return False
    dof = n - 3
    d = points - points.mean(axis=0)
    eig = np.linalg.eigvalsh(d.T @ d)
    bound = (dof + PLANAR_NOISE_SIGMAS * math.sqrt(2.0 * dof)) / n
    return float(eig[0]) / n <= bound * float(np.mean(np.square(noise)))


def _fold_candidates(points: NDArray[np.float64], normals: NDArray[np.float64],
                     patches: NDArray[np.int64], noise: NDArray[np.float64], min_piece: int,
                     min_angle: float) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Find the patches :func:`_split_folds` splits and the side of each of their points.

    Returns side (M,) bool (meaningful inside the split patches) and split (P,) bool.
    """
    n_p = int(patches.max()) + 1
    order = np.argsort(patches, kind="stable")
    starts = np.searchsorted(patches[order], np.arange(n_p + 1))
    side = np.zeros(len(points), dtype=np.bool_)
    split = np.zeros(n_p, dtype=np.bool_)
    for pid in np.flatnonzero(np.diff(starts) >= 2 * min_piece):
        idx = order[starts[pid]:starts[pid + 1]]
        s, angle, middle, core = _fold_sides(normals[idx])
        if angle <= min_angle or middle > FOLD_MIDDLE_SHARE:
            continue
        if min(int(s.sum()), int((~s).sum())) < min_piece:
            continue
        q, nr = points[idx], normals[idx]
        # A convex object's faces meet at convex folds only; at a concave one the normals
        # turn against the way from one side's centroid to the other's.
        if float((q[s].mean(axis=0) - q[~s].mean(axis=0))
                 @ (nr[s].mean(axis=0) - nr[~s].mean(axis=0))) >= 0.0:
            continue
        # A face on one side at least, and the fold seen above the noise: the patch as a
        # whole is no plane within it.
        if _planar_face(points[idx[core]], noise[idx[core]]) or not (
                _planar_face(points[idx[s & core]], noise[idx[s & core]])
                or _planar_face(points[idx[~s & core]], noise[idx[~s & core]])):
            continue
        side[idx] = s
        split[pid] = True
    return side, split


def _split_folds(points: NDArray[np.float64], normals: NDArray[np.float64],
                 nbrs: NDArray[np.int64], sqdist: NDArray[np.float64],
                 patches: NDArray[np.int64], max_edge: float, noise: NDArray[np.float64],
                 min_piece: int, min_angle: float) -> NDArray[np.int64]:
    """Split patches that are two faces met at a fold crossed in small normal turns.

    A patch grows over links whose normals turn by less than the face angle, so two
    faces that meet at a fold which the normal estimate rounds over a few neighbourhoods
    (two touching boxes under Kinect noise) grow into one. Such a patch's normals fall
    into two clusters (:func:`_fold_sides`) farther apart than ``min_angle`` [rad] (no one
    link may turn so far), few of them in between (a surface that turns steadily, a can's
    side or a sphere, fills the middle), and at least one cluster lies on a plane within
    the noise (:func:`_planar_face` over the normals outside the middle: a face, not a
    bowl's two curved sides) while the whole patch does not (the fold stands out of the
    noise: at a far range's noise a small patch is a plane whatever its normals), and the
    fold is concave (a convex object's faces meet at
    convex folds only, and their border votes would join them again). Each side's
    connected pieces of at least ``min_piece`` points become patches (the largest keeps the
    patch's id, so ids stay 0 .. P-1 for the ones below P); smaller pieces return to the
    piece of the same patch they touch most, else the largest. Whether the pieces are one
    object is left to the border votes, as for any two patches.

    Returns
    -------
    (M,) int64 array
        Patch ids, the new pieces numbered from the old count on.
    """
    side, split = _fold_candidates(points, normals, patches, noise, min_piece, min_angle)
    n_p = len(split)
    if not split.any():
        return patches
    m = len(points)
    inside = split[patches]
    keep = inside[:, None] & (patches[nbrs] == patches[:, None]) \
        & (side[nbrs] == side[:, None]) & (nbrs != np.arange(m)[:, None]) \
        & (sqdist <= max_edge * max_edge)
    _, comp = link_components(nbrs, keep)
    comp = np.where(inside, comp, -1).astype(np.int64)
    size = np.bincount(comp[inside], minlength=int(comp.max()) + 1)
    small = inside & (size[np.maximum(comp, 0)] < min_piece)
    # Small pieces join the big piece of their patch their points link to most.
    for _ in range(FOLD_ITERATIONS):
        if not small.any():
            break
        nb = nbrs[small]
        cand = np.where((~small[nb]) & (patches[nb] == patches[small][:, None])
                        & (nb >= 0), comp[nb], -1)
        best = cand.max(axis=1)
        fill = best >= 0
        rows = np.flatnonzero(small)[fill]
        comp[rows] = best[fill]
        small[rows] = False
    out = patches.copy()
    big = inside & ~small
    # The largest piece of a patch keeps its id; the others are numbered on.
    piece_patch = np.full(len(size), -1, dtype=np.int64)
    piece_patch[comp[big]] = patches[big]
    pieces = np.flatnonzero(piece_patch >= 0)
    if not len(pieces):
        return patches  # every piece below min_piece: nothing to part
    rank = np.lexsort((-size[pieces], piece_patch[pieces]))
    pieces = pieces[rank]
    first = np.r_[True, piece_patch[pieces][1:] != piece_patch[pieces][:-1]]
    new_id = np.full(len(size), -1, dtype=np.int64)
    new_id[pieces[first]] = piece_patch[pieces[first]]
    new_id[pieces[~first]] = n_p + np.arange(int((~first).sum()))
    out[big] = new_id[comp[big]]
    # Leftover small points keep the patch's id (its largest piece).
    return out


def _planar_within_noise(off_plane: NDArray[np.float64], noise: NDArray[np.float64],
                         nbrs: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Tell which points' neighbourhoods lie on their plane within the points' own noise.

    A neighbourhood of k points with independent noise sigma_j along the normal and no
    shape of its own lies off its best plane by a mean square of about (k - 3) / k times
    the mean of sigma_j^2 (three degrees of freedom go to the plane), with a standard
    deviation of sqrt(2 (k - 3)) / k times it; :data:`PLANAR_NOISE_SIGMAS` standard
    deviations above that mean is the most the noise alone gives. A surface variation
    above ``edge_variation_threshold`` there is the noise's, not an edge's: under
    Kinect-class noise at 1 m a box face seen face-on (the noise along its normal) has a
    variation of 0.06-0.08 over its whole area, its neighbours seen obliquely 0.01-0.02,
    and a face made of edge points falls to its neighbours' faces, point by point, as
    far as 20 mm from its edges.

    Parameters
    ----------
    off_plane : (M,) float64 array [m^2]
        Mean squared distance of every neighbourhood from its plane.
    noise : (M,) float64 array [m]
        Local noise of every working point, the part its neighbours do not share (e.g.
        :func:`working_noise` over the frame's ``scale``; 0 where unknown: never planar
        by the noise).
    nbrs : (M, k) int64 array
        The neighbourhoods (the point itself among them).

    Returns
    -------
    (M,) bool array
    """
    k = nbrs.shape[1]
    dof = max(k - 3, 1)
    bound = (dof + PLANAR_NOISE_SIGMAS * math.sqrt(2.0 * dof)) / k
    expected = np.square(noise)[nbrs].mean(axis=1)
    return off_plane <= bound * _seen_noise_share(off_plane, expected, dof, k) * expected


def _seen_noise_share(off_plane: NDArray[np.float64], expected: NDArray[np.float64],
                      dof: int, k: int) -> float:
    """Return the share of the modelled noise variance the neighbourhoods show.

    Most neighbourhoods of a frame lie on smooth surfaces, so the median of their mean
    squared distance from their plane over the modelled variance is, for independent
    noise, the median of a chi-square with ``dof`` degrees of freedom over ``k``
    (Wilson-Hilferty: dof (1 - 2 / (9 dof))^3). A real sensor's noise is correlated
    between neighbouring pixels (disparity terraces, the stereo matcher's window), so a
    neighbourhood of working points lies far flatter than the model says: in the office
    scene of the PCL tutorials the median is a tenth of it, every neighbourhood passes a
    bound on the model's variance, edges and grooves included, and faces grow from
    normals the noise turned. The other way, working points averaging many pixels each (a
    camera of twice the Kinect's pixels per degree: 4-6 per 4 mm voxel at 1 m) lie
    farther off their planes than sigma / sqrt(count) says (likely because a voxel's walls
    select its points by their noise): there the median is twice the model's and a bound
    on the model cut smooth faces into edge points. The bound is taken on the variance the
    frame shows, either way.

    Parameters
    ----------
    off_plane, expected : (M,) float64 arrays [m^2]
        Mean squared distance of every neighbourhood from its plane and its modelled noise
        variance (0 where the noise is unknown).
    dof, k : int
        Degrees of freedom of the residual and neighbours per neighbourhood.

    Returns
    -------
    float
    """
    known = expected > 0
    if not known.any():
        return 1.0
    chi2_median = dof * (1.0 - 2.0 / (9.0 * dof)) ** 3 / k
    return float(np.median(off_plane[known] / expected[known])) / chi2_median


def level_quantum(points: NDArray[np.float64], inverse: NDArray[np.int64],
                  counts: NDArray[np.int64], step: float | None, spacing: float = 0.0
                  ) -> NDArray[np.float64]:
    """Depth quantisation [m] left in every working point after the averaging.

    A working point whose input points all lie on one disparity level (their depths spread
    less than :data:`LEVEL_SPREAD` of a depth step) keeps the level's whole error, up to
    one depth step ``step * z**2`` between two such points, and so do its neighbours on the
    same terrace: the error is shared along a terrace edge, not averaged. A working point
    averaging points of several levels has its quantisation spread into noise, which the
    frame's noise already holds (0 there). So has one where a depth step is no longer than
    the working points' ``spacing`` [m]: the grid does not resolve the terraces, its normals
    see the staircase as one slope (hand geometry, quantised planes at 0.6-1 m and a 4 mm
    grid: border folds within 0.09 of a step; at 1.5-3 m, steps of 1.6-3.3 spacings: up to
    0.49, :data:`QUANTUM_FOLD_STEPS`), as the terrace join counts a surface parted only
    where a step is longer than a link (:func:`geomodel_ros.core.joins.join_terraces`).

    Parameters
    ----------
    points : (N, 3) float64 array [m]
        Finite input points, optical axis along +z or -z.
    inverse : (N,) int64 array
        Working point of every input point.
    counts : (M,) int64 array
        Input points per working point.
    step : float or None
        The frame's disparity step in 1/z [1/m] (:func:`disparity_step`); None for a frame
        whose depths are not quantised (all 0).
    spacing : float
        Spacing of the working points [m] (``seg_voxel_size``).

    Returns
    -------
    (M,) float64 array [m]
    """
    if step is None:
        return np.zeros(len(counts))
    z = np.abs(points[:, 2])
    n = np.maximum(counts, 1)
    mean = np.bincount(inverse, weights=z, minlength=len(counts)) / n
    var = np.bincount(inverse, weights=np.square(z - mean[inverse]), minlength=len(counts)) / n
    depth_step = step * np.square(mean)
    # Depths near float64's range (a malformed cloud's 1e80 m) square to inf: a level.
    with np.errstate(over="ignore"):
        level = (var < np.square(LEVEL_SPREAD * depth_step)) & (depth_step > spacing)
    return np.where(level, depth_step, 0.0)


def _border_votes(points: NDArray[np.float64], normals: NDArray[np.float64],
                  nbrs: NDArray[np.int64], sqdist: NDArray[np.float64],
                  patches: NDArray[np.int64], n_p: int, max_edge: float, tolerance: float,
                  step: NDArray[np.float64], parallel_cos: float = 1.0,
                  whole: tuple[NDArray, NDArray] | None = None, crease_angle: float = 0.0
                  ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray, NDArray,
                             NDArray[np.bool_] | None]:
    """Convexity votes of the neighbour links across each border of two patches.

    Every link i -> j (``nbrs`` (M, k), squared lengths ``sqdist`` [m^2]) between two
    patches and no longer than ``max_edge`` [m] (a longer one spans a depth jump) votes
    with its convexity (n_i - n_j) . (p_i - p_j) / |p_i - p_j| (~0 flat, > 0 convex, < 0
    concave); the vote is *yes* when it is at least ``-tolerance`` and the link crosses no
    step (:func:`_step_free` with ``step`` (M,) [m] and ``parallel_cos``: two parallel faces
    at different heights have a convexity of 0 but are no continuation of one surface).

    With ``whole`` = (working-point noise (M,) [m] (:func:`working_noise`), the depth
    quantisation left in each working point (M,) [m] (:func:`level_quantum`)) each border
    is also tested as a whole for a crease (:func:`_creased_borders`), its floor the
    per-link concavity tolerance. A border holds no crease, whatever its folds, where its
    two sides turn by less than ``crease_angle`` [rad] both by the patches' mean normals
    (:func:`_patch_turn`) and by their normals near it (:func:`_border_turn`): pieces of
    one face that a frame's slowly varying error bends are cut where they bend most, so
    the fold across the cut is concave by selection.

    Returns
    -------
    a, b : (P,) int64 arrays
        The two patches of each adjacent pair, ``a < b``, pairs in increasing order.
    votes, yes : (P,) arrays
        Number of links across each pair's border, and of yes votes among them.
    creased : (P,) bool array or None
        Borders with a crease along their whole length (None without ``whole``).
    """
    m, k = nbrs.shape
    i = np.repeat(np.arange(m), k)
    j = nbrs.ravel()
    within = sqdist.ravel() <= max_edge * max_edge
    ok = (patches[i] != patches[j]) & within
    dist = np.sqrt(sqdist.ravel()[ok])
    below_i, below_j, no_step = _step_free(points, normals, i[ok], j[ok], step, parallel_cos)
    good = (below_i + below_j >= -tolerance * dist) & no_step
    pi, pj = patches[i[ok]], patches[j[ok]]
    key = np.minimum(pi, pj) * n_p + np.maximum(pi, pj)
    pairs, inv = np.unique(key, return_inverse=True)
    votes = np.bincount(inv, minlength=len(pairs))
    yes = np.bincount(inv, weights=good, minlength=len(pairs))
    creased = None if whole is None else np.zeros(len(pairs), dtype=bool)
    if whole is not None and len(pairs):
        noise_w, quantum = whole
        inner = np.flatnonzero(within & ~ok)
        inner = inner[::max(1, len(inner) // NULL_LINKS)]
        null = link_folds(points, normals, i[inner], j[inner])
        noise_in = np.minimum(noise_w[i[inner]], noise_w[j[inner]])
        has = noise_in > 0  # no noise unit where the noise is unknown (0)
        units = null[has] / noise_in[has]
        spread = robust_sigma(units[np.isfinite(units)])
        links = np.stack([0.5 * (below_i + below_j), np.minimum(noise_w[i[ok]], noise_w[j[ok]]),
                          0.5 * tolerance * dist, 0.5 * (quantum[i[ok]] + quantum[j[ok]])])
        creased = _creased_borders(inv, len(pairs), i[ok], pi < pj, links, spread)
        if crease_angle > 0.0 and creased.any():
            rows = np.flatnonzero(creased)
            a_r, b_r = pairs[rows] // n_p, pairs[rows] % n_p
            # The patches' means first (one sum per patch); the normals near the border
            # only where the means turn by less.
            flat = _patch_turn(normals, patches, n_p, a_r, b_r) < crease_angle
            rows, a_r, b_r = rows[flat], a_r[flat], b_r[flat]
            if len(rows):
                creased[rows] = _border_turn(points, normals, patches, a_r, b_r, inv, rows,
                                             i[ok], j[ok], BORDER_TURN_LINKS * max_edge) \
                    >= crease_angle
    return pairs // n_p, pairs % n_p, votes, yes, creased


def _patch_turn(normals: NDArray[np.float64], patches: NDArray[np.int64], n_p: int,
                a: NDArray[np.int64], b: NDArray[np.int64]) -> NDArray[np.float64]:
    """Angle [rad] between the mean normals of patches ``a`` and ``b`` (P,) each."""
    sums = np.stack([np.bincount(patches, weights=normals[:, c], minlength=n_p)
                     for c in range(3)], axis=1)
    sums /= np.maximum(np.linalg.norm(sums, axis=1, keepdims=True), _FOLD_TINY)
    cos = np.einsum("ij,ij->i", sums[a], sums[b])
    return np.arccos(np.clip(cos, -1.0, 1.0))


#: The two sides' normals of a border are taken over the points of each patch within this
#: many links (``max_edge``) of the border's centroid: a curved patch's mean normal is
#: not its normal at the border, while the points at the border blend both sides.
BORDER_TURN_LINKS = 2.0


def _border_turn(points: NDArray[np.float64], normals: NDArray[np.float64],
                 patches: NDArray[np.int64], a: NDArray[np.int64], b: NDArray[np.int64],
                 inv: NDArray[np.int64], rows: NDArray[np.int64], i: NDArray[np.int64],
                 j: NDArray[np.int64], radius: float) -> NDArray[np.float64]:
    """Angle [rad] between the two sides' normals of the borders ``rows`` (R,).

    ``a``, ``b`` (R,) are each border's patches, ``inv`` (L,) the border of every
    cross-border link ``i`` -> ``j`` (L,). Each side's normal is the sum of the unit
    normals of its patch's points within ``radius`` [m] of the border's centroid (the mean
    of its links' ends), leaving out the points at the border (an end of one of its
    links), whose neighbourhoods straddle both sides (hand-built borders concave by 12 deg
    each side under a Kinect's local and slowly varying noise: the border points' own
    normals turned by less than 11.5 deg on 8 of 12 seeds); all of the patch's points
    where none lie there.
    """
    order, ids, starts, stops = group_by_label(np.arange(len(patches)), patches)
    member_span = dict(zip(ids.tolist(), zip(starts.tolist(), stops.tolist())))
    sel = np.flatnonzero(np.isin(inv, rows))
    link_order, ids, starts, stops = group_by_label(sel, inv[sel])
    link_span = dict(zip(ids.tolist(), zip(starts.tolist(), stops.tolist())))
    at_border = np.zeros(len(points), dtype=bool)
    out = np.zeros(len(rows))
    for k, (row, pa, pb) in enumerate(zip(rows.tolist(), a.tolist(), b.tolist())):
        links = link_order[slice(*link_span[row])]
        ends = np.concatenate([i[links], j[links]])
        at_border[ends] = True
        centre = points[ends].mean(axis=0)
        sides = []
        for p in (pa, pb):
            members = order[slice(*member_span[p])]
            near = members[(np.sum(np.square(points[members] - centre), axis=1)
                            <= radius * radius) & ~at_border[members]]
            sides.append(normals[near if len(near) else members].sum(axis=0))
        at_border[ends] = False
        norm = float(np.linalg.norm(sides[0]) * np.linalg.norm(sides[1]))
        out[k] = math.acos(min(1.0, max(-1.0, float(sides[0] @ sides[1]) / max(norm, _FOLD_TINY))))
    return out


def _surface_pass_rate(points: NDArray[np.float64], normals: NDArray[np.float64],
                       nbrs: NDArray[np.int64], sqdist: NDArray[np.float64],
                       patches: NDArray[np.int64], max_edge: float, tolerance: float,
                       step: NDArray[np.float64], noisy: NDArray[np.bool_],
                       parallel_cos: float = 1.0) -> float:
    """Return the share of the noisy links inside the patches that pass the border vote.

    A border's link votes yes when it is flat or convex within ``tolerance`` and crosses no
    step (:func:`_border_votes`); both tests are tests against the noise (the step at
    :data:`STEP_NOISE_SIGMAS` of it, the concavity tolerance a fixed share of the link
    that the noise of two normals exceeds), so under a frame's noise a link on one smooth
    surface passes them only by chance, not always. Inside a patch every link lies on one
    smooth surface: the share of them that pass is what one surface gives in this frame.
    Only links whose step the noise sets at both ends (``noisy``) count (links to the
    point itself left out; an even stride of at most about :data:`NULL_LINKS` of them):
    where the noise is below the fixed step floor the tests are exact, and a link that
    fails them there meets a real edge or fold. It is at least :data:`MIN_PASS_RATE`.

    Parameters
    ----------
    points, normals : (M, 3) float64 arrays
        Working points [m] and unit normals oriented towards the sensor.
    nbrs, sqdist : (M, k) arrays
        Nearest neighbours and their squared distances [m^2].
    patches : (M,) int64 array
        Patch of every point.
    max_edge : float
        Longest link [m].
    tolerance : float
        Concavity tolerance of a vote (fold per link length, ``seg_concavity_tolerance``).
    step : (M,) float64 array
        Largest step [m] within one surface at each point (:func:`_step_free`).
    noisy : (M,) bool array
        Points whose step is set by their noise (not by the fixed floor).
    parallel_cos : float
        Normals of parallel surfaces agree within this cosine (:func:`_step_free`).

    Returns
    -------
    float
        In [:data:`MIN_PASS_RATE`, 1]; 1 where the patches hold no noisy link.
    """
    m, k = nbrs.shape
    i = np.repeat(np.arange(m), k)
    j = nbrs.ravel()
    inner = np.flatnonzero((patches[i] == patches[j]) & (i != j) & noisy[i] & noisy[j]
                           & (sqdist.ravel() <= max_edge * max_edge))
    if not len(inner):
        return 1.0
    inner = inner[::max(1, len(inner) // NULL_LINKS)]
    below_i, below_j, no_step = _step_free(points, normals, i[inner], j[inner], step,
                                           parallel_cos)
    good = (below_i + below_j >= -tolerance * np.sqrt(sqdist.ravel()[inner])) & no_step
    return max(MIN_PASS_RATE, float(good.mean()))


def _outlines(points: NDArray[np.float64], normals: NDArray[np.float64], nbrs: NDArray[np.int64],
              sqdist: NDArray[np.float64], patches: NDArray[np.int64], a: NDArray[np.int64],
              b: NDArray[np.int64], params: ModelingParams, noise: NDArray[np.float64],
              quantum: NDArray[np.float64] | None) -> NDArray[np.bool_]:
    """Borders (P,) of the patch pairs ``a``, ``b`` that are an outline over a surface behind.

    :func:`_occluding_borders` over the points at a surface's rim (:func:`_rim_points`) or
    next to another patch, with the working points' local ``noise`` (M,) [m] and depth
    ``quantum`` (M,) [m], the patches behind judged by :func:`_concave_patches`.

    Two objects that touch are often seen one in front of the other: where they meet in
    the image the depth jumps by centimetres (an outline over the surface behind it), and
    they are linked in 3-D only near the contact, whose few links vote like one smooth
    surface under correlated noise. The image seam of two patches is the pairs of image
    neighbours, one in each (nearest by viewing direction, within
    :data:`SEAM_RADIUS_SPACINGS` working-grid spacings as seen from the nearer one); a
    border whose seam holds more than :data:`SEAM_JUMP_SHARE` depth jumps longer than a
    link (``max_edge``) is an outline. A jump is the nearer point lying off the farther
    one's tangent plane by more than a link: neighbours on a face seen at a grazing angle
    are far apart along the ray too, but each lies in the other's plane (a box's top
    beyond its front edge). The noise of the gap, a difference of two neighbours' depths
    (sqrt(noise_i^2 + noise_j^2) of their local noise: the frame's slowly varying error
    is shared by neighbours and cancels), is added to the link (a stereo camera's depth
    at 2 m is noisier than a link), and so is each end's depth quantum where the depths
    are quantised (the terraces of one far plane are a depth step apart, 15-20 mm at
    2.5 m for a Kinect, longer than a link). Patches of one surface meet along a seam without
    jumps. A container's rim is an outline in front of its own inner wall, seen through its
    opening: a concave surface, where a convex object behind another shows a flat or convex
    one. So a border is no outline where the patch behind it (the farther end of most of
    its jumps) is ``concave``: there the border votes decide as before.
    """
    n_p = int(patches.max()) + 1
    max_edge = params.seg_max_edge_factor * params.seg_voxel_size
    edge = _rim_points(points, normals, nbrs, params.seg_voxel_size) \
        | (patches[nbrs] != patches[:, None]).any(axis=1)
    return _occluding_borders(
        points, normals, patches, a, b, n_p, params.seg_voxel_size, max_edge, edge, noise,
        quantum, lambda behind: _concave_patches(points, normals, nbrs, sqdist, patches, n_p,
                                                 max_edge, behind))


def _occluding_borders(points: NDArray[np.float64], normals: NDArray[np.float64],
                       patches: NDArray[np.int64], a: NDArray[np.int64], b: NDArray[np.int64],
                       n_p: int, spacing: float, max_edge: float,
                       edge: NDArray[np.bool_] | None = None,
                       noise: NDArray[np.float64] | None = None,
                       quantum: NDArray[np.float64] | None = None,
                       concave: Callable[[NDArray[np.int64]], NDArray[np.bool_]] | None = None
                       ) -> NDArray[np.bool_]:
    """Tell which patch borders are mostly one patch's outline in front of the other.

    A border whose image seam (:func:`_image_seam`) holds more than
    :data:`SEAM_JUMP_SHARE` depth jumps longer than a link (``max_edge``, plus the noise
    of a difference of two neighbours and both ends' depth quanta) is an outline, unless
    the patch behind it is ``concave``; why, in :func:`_outlines`.

    Parameters
    ----------
    points, normals : (M, 3) float64 arrays
        Working points [m], sensor at the origin, and their unit normals.
    patches : (M,) int64 array
        Patch of every point.
    a, b : (P,) int64 arrays
        The two patches of each border, ``a < b``, in increasing order of ``a * n_p + b``.
    n_p : int
        Number of patches.
    spacing : float
        Spacing of the working points [m].
    max_edge : float
        Longest link [m].
    edge : (M,) bool array, optional
        The points that may lie on a seam (default all), e.g. those at the rim of their
        surface (:func:`_rim_points`) or next to another patch: a point inside one surface,
        its nearest neighbours all around it on its own patch, has its image neighbours
        there too.
    noise : (M,) float64 array, optional
        Local noise [m] of every working point, the part its neighbours do not share (e.g.
        :func:`working_noise` over the frame's ``scale``); default 0.
    quantum : (M,) float64 array, optional
        Depth quantisation [m] left in every working point (:func:`level_quantum`);
        default 0.
    concave : callable, optional
        Given patch ids (Q,), tell which are concave as seen from the sensor ((n_p,) bool
        array, e.g. :func:`_concave_patches`); asked only for the patches behind outlines.

    Returns
    -------
    (P,) bool array
    """
    rows = np.arange(len(points)) if edge is None else np.flatnonzero(edge)
    if len(a) == 0 or len(rows) < 2:
        return np.zeros(len(a), dtype=bool)
    i, j, far = _image_seam(points, rows, patches, spacing)
    gap = np.abs(np.einsum("ij,ij->i", normals[far], points[i] - points[j]))
    limit = np.full(len(i), max_edge)
    if noise is not None:
        limit += np.hypot(noise[i], noise[j])
    if quantum is not None:
        limit += quantum[i] + quantum[j]
    jump = gap > limit
    key = np.minimum(patches[i], patches[j]) * n_p + np.maximum(patches[i], patches[j])
    pairs = a * n_p + b
    pos = np.minimum(np.searchsorted(pairs, key), len(pairs) - 1)
    on = pairs[pos] == key
    seam = np.bincount(pos[on], minlength=len(pairs))
    jumps = np.bincount(pos[on], weights=jump[on], minlength=len(pairs))
    outline = jumps > SEAM_JUMP_SHARE * seam
    if concave is None:
        return outline
    # The farther end of each jump is the patch behind; per border, the side with most.
    jump_on = on & jump
    a_behind = np.bincount(pos[jump_on], weights=patches[far[jump_on]] == a[pos[jump_on]],
                           minlength=len(pairs))
    behind = np.where(2 * a_behind >= jumps, a, b)
    if outline.any():
        outline[outline] = ~concave(np.unique(behind[outline]))[behind[outline]]
    return outline


def _image_seam(points: NDArray[np.float64], rows: NDArray[np.int64],
                patches: NDArray[np.int64], spacing: float
                ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Pairs (i, j) of image neighbours among the points ``rows`` that lie on two patches.

    Neighbours by viewing direction (the :data:`SEAM_NEIGHBORS` nearest), kept within
    :data:`SEAM_RADIUS_SPACINGS` working-grid ``spacing`` [m] as seen from the nearer
    point; also returns the farther point of each pair (the one behind). The search
    stops at the widest angle any pair can be kept at (that seen from the nearest point
    of ``rows``, with :data:`SEAM_BOUND_MARGIN`): the nearest within it are the first of
    the :data:`SEAM_NEIGHBORS` nearest, the others would not be kept.
    """
    ranges = np.linalg.norm(points, axis=1)
    tiny = np.finfo(float).tiny
    dirs = points[rows] / np.maximum(ranges[rows], tiny)[:, None]
    k = min(SEAM_NEIGHBORS, len(rows))
    radius = SEAM_RADIUS_SPACINGS * spacing
    widest = radius / max(float(ranges[rows].min()), tiny) * (1.0 + SEAM_BOUND_MARGIN)
    angle, nb = cKDTree(dirs).query(dirs, k=k, distance_upper_bound=widest,
                                    workers=-1 if len(rows) >= THREADED_QUERIES else 1)
    found = nb.ravel() < len(rows)  # beyond the bound: index len(rows), angle inf
    i = np.repeat(rows, k)[found]
    j = rows[nb.ravel()[found]]
    near = angle.ravel()[found] * np.minimum(ranges[i], ranges[j]) <= radius
    near &= patches[i] != patches[j]
    i, j = i[near], j[near]
    return i, j, np.where(ranges[i] > ranges[j], i, j)


def _rim_points(points: NDArray[np.float64], normals: NDArray[np.float64],
                nbrs: NDArray[np.int64], spacing: float) -> NDArray[np.bool_]:
    """Tell which working points lie at the rim of their surface (an outline in the image).

    Inside a surface a point's nearest neighbours surround it and their centroid lies on
    it; at the surface's rim they lie on one side, their centroid about a spacing away
    along the surface (k = 16 neighbours on a square grid at a straight rim: 1.2
    spacings; one row in: 0.6). A point is at the rim where that tangential offset exceeds
    :data:`RIM_OFFSET_SPACINGS` of the working ``spacing`` [m].
    """
    offset = np.zeros(points.shape)
    for c in range(points.shape[1]):
        col = np.ascontiguousarray(points[:, c])
        offset[:, c] = col[nbrs].mean(axis=1) - col
    offset -= np.einsum("ij,ij->i", offset, normals)[:, None] * normals
    return np.einsum("ij,ij->i", offset, offset) > (RIM_OFFSET_SPACINGS * spacing) ** 2


def _concave_patches(points: NDArray[np.float64], normals: NDArray[np.float64],
                     nbrs: NDArray[np.int64], sqdist: NDArray[np.float64],
                     patches: NDArray[np.int64], n_p: int, max_edge: float,
                     which: NDArray[np.int64] | None = None) -> NDArray[np.bool_]:
    """Tell which patches are concave as seen from the sensor (a container's inner wall).

    The fold of a link inside a patch (:func:`~.faces.link_folds`) is about l^2 / (2 r) on a
    surface of radius r bent away from the sensor (convex), 0 on a plane and negative on
    one bent towards it (concave); a patch is concave where the median fold of its links
    is negative. No margin: the sign alone is what tells a surface seen from inside from
    one seen from outside, and the noise does not make a plane concave (the normals' own
    noise lifts a plane's median fold slightly above 0). Measured on the patches behind
    the outlines of the clutter benchmark under ``KINECT_REAL_NOISE`` (20 scenes,
    scratch): every cup and bowl inner wall behind its own rim has a negative median
    fold (19 of 19, -0.008 to -0.12 mm), the patches behind another object's outline a
    positive one in 49 of 55 (flat faces +0.006 to +0.03 mm, round sides up to +0.3 mm;
    four of the six others are cup inner walls behind another object). At a 3-standard-
    error margin none of the 19 was concave, and their cups fell apart.

    Parameters
    ----------
    points, normals : (M, 3) float64 arrays
        Working points [m] and their unit normals oriented towards the sensor.
    nbrs, sqdist : (M, k) arrays
        Nearest neighbours and their squared distances [m^2].
    patches : (M,) int64 array
        Patch of every point, 0 .. n_p-1.
    n_p : int
    max_edge : float
        Longest link [m].
    which : (Q,) int64 array, optional
        The patches to judge (default all); the others are not concave.

    Returns
    -------
    (n_p,) bool array
    """
    k = nbrs.shape[1]
    rows = np.arange(len(points)) if which is None else \
        np.flatnonzero(np.isin(patches, which))
    i = np.repeat(rows, k)
    j = nbrs[rows].ravel()
    own = np.repeat(patches[rows], k)
    inside = np.flatnonzero((own == patches[j]) & (i != j)
                            & (sqdist[rows].ravel() <= max_edge * max_edge))
    concave = np.zeros(n_p, dtype=bool)
    if not len(inside):
        return concave
    fold = link_folds(points, normals, i[inside], j[inside])
    own = own[inside]
    present = np.bincount(own, minlength=n_p) > 0
    ids = np.flatnonzero(present)
    # The rank of each link's patch among those present (np.unique's inverse, no sort).
    concave[ids] = _group_median_negative((np.cumsum(present) - 1)[own], fold, len(ids))
    return concave


def _group_median(group: NDArray[np.int64], values: NDArray[np.float64], n: int
                  ) -> NDArray[np.float64]:
    """Return the median (n,) of ``values`` (L,) within each ``group`` (L,) id 0 .. n-1.

    Every group must hold at least one value. The values are sorted once, then grouped by
    a stable sort of their groups (a radix sort for up to ``MAX_INT16_LABEL`` groups):
    each group's values in ascending order, as a sort by group and value gives them.
    """
    by_value = np.argsort(values)
    within = group[by_value]
    order = by_value[np.argsort(within.astype(np.int16) if n <= MAX_INT16_LABEL + 1 else within,
                                kind="stable")]
    v = values[order]
    counts = np.bincount(group, minlength=n)
    start = np.cumsum(counts) - counts
    return 0.5 * (v[start + (counts - 1) // 2] + v[start + counts // 2])


def _group_median_negative(group: NDArray[np.int64], values: NDArray[np.float64], n: int
                           ) -> NDArray[np.bool_]:
    """Tell, as ``_group_median(group, values, n) < 0``, which groups' medians are negative.

    Arguments as in :func:`_group_median`. Only the sign is asked, so the values need no
    sort: a group's two middle values (the same one for an odd count) are both negative
    where more of its values than the upper one's rank are, and neither is where no more
    than the lower one's rank are; their mean then has their sign. Only a group of an even
    count with exactly half of its values negative needs the two values themselves
    (:func:`_group_median` on that group's values alone).
    """
    counts = np.bincount(group, minlength=n)
    negative = np.bincount(group[values < 0.0], minlength=n)
    out = negative > counts // 2
    tie = np.flatnonzero((counts % 2 == 0) & (negative == counts // 2) & (counts > 0))
    if len(tie):
        rank = np.full(n, -1, dtype=np.int64)
        rank[tie] = np.arange(len(tie))
        at = np.flatnonzero(rank[group] >= 0)
        out[tie] = _group_median(rank[group[at]], values[at], len(tie)) < 0.0
    return out


def _creased_borders(inv: NDArray[np.int64], n_pairs: int, i: NDArray[np.int64],
                     lower: NDArray[np.bool_], links: NDArray[np.float64], spread: float
                     ) -> NDArray[np.bool_]:
    """Tell which patch borders hold a crease, from the median fold of their links.

    The per-link votes judge each link alone: under noise a shallow contact crease (two
    objects touching) lets 30-50 % of them pass, and a majority may join the two. Along a
    whole border the fold keeps its value while the noise of its median shrinks like
    1 / sqrt(independent votes): one vote per point spacing along the border, (border
    points of the side with fewer) / :data:`BORDER_STRIP_POINTS`, at least 1. A border
    holds a crease where its median fold < -max(its mean floor, E ``spread`` x its mean
    frame noise, :data:`QUANTUM_FOLD_STEPS` x its mean quantum), E =
    :data:`BORDER_CREASE_SIGMAS` x :data:`MEDIAN_STANDARD_ERROR` / sqrt(votes). The fold
    carries the normals' error times the link length, and the frame's slowly varying error
    bends the surface, so it is judged against the frame's noise. The quantum (a depth
    step where a working point holds one disparity level, 0 elsewhere) does not shrink
    with the votes: a terrace's error is shared along it; and on such terraces most links
    inside a patch have a fold of exactly 0, so the measured spread vanishes there.

    Parameters
    ----------
    inv : (L,) int64 array
        Border (pair) of every cross-border link, 0 .. n_pairs-1.
    n_pairs : int
    i : (L,) int64 array
        The link's first point.
    lower : (L,) bool array
        That point is in the pair's lower patch (it counts on that side of the border).
    links : (4, L) float64 array
        Per link: fold [m] (:func:`~.faces.link_folds`), frame noise [m] (the smaller of its two
        ends'), smallest fold of a crease [m] (the per-link concavity tolerance), depth
        quantisation [m] (the mean of its two ends' :func:`level_quantum`).
    spread : float
        Robust sigma of the fold in frame noise units, measured on the links inside the
        patches (one smooth surface each).

    Returns
    -------
    (n_pairs,) bool array
    """
    cell = inv * 2 + lower
    _, first = np.unique(cell * (int(i.max(initial=0)) + 1) + i, return_index=True)
    side = np.bincount(cell[first], minlength=2 * n_pairs).reshape(-1, 2)
    error = BORDER_CREASE_SIGMAS * MEDIAN_STANDARD_ERROR \
        / np.sqrt(np.maximum(side.min(axis=1) / BORDER_STRIP_POINTS, 1.0))
    links_per = np.maximum(np.bincount(inv, minlength=n_pairs), 1)
    frame, tol, quantum = (np.bincount(inv, weights=w, minlength=n_pairs) / links_per
                           for w in links[1:])
    return _group_median(inv, links[0], n_pairs) < -np.maximum(
        np.maximum(tol, error * spread * frame), QUANTUM_FOLD_STEPS * quantum)


def _patch_normals(points: NDArray[np.float64], normals: NDArray[np.float64],
                   nbrs: NDArray[np.int64], patches: NDArray[np.int64],
                   noise: NDArray[np.float64], off_plane: NDArray[np.float64] | None = None,
                   refit: NDArray[np.bool_] | None = None) -> NDArray[np.float64]:
    """Re-estimate the normals of points next to a crease from their own patch.

    Near a crease a point's neighbourhood straddles both surfaces and its normal blends
    them, which blurs the convexity of the links across the crease; restricted to its own
    patch the neighbourhood holds one surface. Such a neighbourhood is told by its points
    lying off their best plane by more than the surface's noise (RMS above ``noise``);
    elsewhere (one smooth surface cut into patches by its noisy normals) the whole
    neighbourhood gives the better normal, and a one-sided one from a few noisy points
    would turn the links across the patch border concave. Points with fewer than
    :data:`PATCH_NORMAL_MIN_NEIGHBORS` neighbours in their patch also keep ``normals``.
    Points ``refit`` marks are refitted whatever their residual: a point made smooth by
    the noise test (:func:`_planar_within_noise`) with a variation above the edge
    threshold is often one whose neighbourhood rounds over a crease within the noise,
    and its blended normal would vote the crease's links concave or stepped.

    Parameters
    ----------
    points, normals : (M, 3) float64 arrays
        Working points [m] (sensor at the origin) and their unit normals.
    nbrs : (M, k) int64 array
        Nearest neighbours of every point (itself among them).
    patches : (M,) int64 array
        Patch of every point.
    noise : (M,) float64 array
        Noise [m] of the surface along its normal at each point (e.g.
        :func:`working_noise`; 0 where unknown: every border point takes its own patch's
        normal).
    off_plane : (M,) float64 array [m^2], optional
        Mean squared distance of every point's neighbourhood from its plane, when known
        (:func:`geomodel_ros.core.faces.pca_normals` over ``nbrs``); computed otherwise.
    refit : (M,) bool array, optional
        Points refitted from their own patch whatever their residual.

    Returns
    -------
    (M, 3) float64 array
        Unit normals oriented towards the sensor.
    """
    same = patches[nbrs] == patches[:, None]
    if off_plane is None:
        off_plane, _ = smallest_eigenpairs_sym(*neighborhood_moments(points, nbrs))
    # Only the points that do not keep their normal are refitted (row by row, the same
    # values as refitting all of them).
    rows = np.flatnonzero((same.sum(axis=1) >= PATCH_NORMAL_MIN_NEIGHBORS)
                          & ((off_plane > noise * noise) if refit is None
                             else (off_plane > noise * noise) | refit))
    own = np.where(same[rows], nbrs[rows], rows[:, None])
    _, own_normals = smallest_eigenpairs_sym(*neighborhood_moments(points, own))
    own_normals[np.einsum("ij,ij->i", own_normals, points[rows]) > 0] *= -1
    refined = normals.copy()
    refined[rows] = own_normals
    return refined


def _step_free(points: NDArray[np.float64], normals: NDArray[np.float64], i: NDArray[np.int64],
               j: NDArray[np.int64], step: NDArray[np.float64], parallel_cos: float = 1.0
               ) -> tuple[NDArray, NDArray, NDArray]:
    """How far each of the links i -> j lies below the tangent planes at its two ends.

    Parameters
    ----------
    points, normals : (M, 3) float64 arrays
        Working points [m] and their unit normals (oriented towards the sensor).
    i, j : (L,) int64 arrays
        The two ends of each link.
    step : (M,) float64 array
        Largest height [m] of a neighbour above a point's tangent plane on one surface
        (at least :data:`STEP_NOISE_SIGMAS` times :func:`working_noise`); a link takes
        the smaller of its two ends': a sparse working point (one input point, the full
        sensor noise: a silhouette, a remnant of the desk beside the support band) does
        not lift the step of its link to a dense surface (on osd_learn with the larger,
        three more objects of 112 came out over-segmented, joined to desk remnants).
    parallel_cos : float
        Links whose two normals agree within this cosine (e.g. of ``face_angle_threshold``:
        one face to the patch growing) are between parallel surfaces; for them the offset
        along the mean normal, (below_i - below_j) / 2, must also stay within the step.
        At a small step (a can's top 2.5 mm above a box's top beside it, noise-free) the
        working points next to it average both levels and their normals tilt towards it:
        measured along the tilted normal the other level lies within the step, along the
        mean normal it does not (clutter benchmark, 20 scenes noise-free: 96.0 % of the
        objects with IoU >= 0.8 and 4.0 % under-segmented, 95.2 / 4.8 % without; Kinect
        noise unchanged, 89.2 / 4.4 %). On one face (below_i ~ -below_j) this is the
        test of the smaller of the two; at a convex or concave fold the normals differ.
        1 (the default): no link is parallel, the test is the smaller offset alone.

    Returns
    -------
    below_i, below_j : (L,) float64 arrays
        n_i . (p_i - p_j) and n_j . (p_j - p_i) [m]: positive where the other end lies below
        the tangent plane (convex), about 0 on a plane, negative above it (concave).
    no_step : (L,) bool array
        Neither end lies above the other's tangent plane by more than ``step``, nor, for
        parallel normals, are the two ends offset along their mean normal by more.
    """
    d = take_rows(points, i) - take_rows(points, j)
    n_i, n_j = take_rows(normals, i), take_rows(normals, j)
    below_i = np.einsum("ij,ij->i", n_i, d)
    below_j = -np.einsum("ij,ij->i", n_j, d)
    limit = np.minimum(step[i], step[j])
    no_step = np.minimum(below_i, below_j) >= -limit
    if parallel_cos < 1.0:
        offset = np.abs(below_i - below_j) > 2.0 * limit
        offset[offset] = np.einsum("ij,ij->i", n_i[offset], n_j[offset]) > parallel_cos
        no_step &= ~offset
    return below_i, below_j, no_step


def _cut_steps(points: NDArray[np.float64], normals: NDArray[np.float64],
               nbrs: NDArray[np.int64], sqdist: NDArray[np.float64],
               patches: NDArray[np.int64], max_edge: float, step: NDArray[np.float64],
               min_piece: int = 1, noisy: NDArray[np.bool_] | None = None,
               parallel_cos: float = 1.0) -> NDArray[np.int64]:
    """Split the smooth patches along the links that cross a step (:func:`_step_free`).

    Smooth patches link neighbours by the angle of their normals alone, so two parallel
    faces of different objects that meet at a small step (a box's top beside a can's top of
    nearly the same height) or touch tangentially form one patch; without the links across
    the step they fall apart into their faces. (Keeping a patch's parts that no link joins
    in one patch instead gave the office floor of ``pcl_scenes`` 38 segments instead of 65
    with the defaults, but three cans of osd_learn lost their cylinder type.)

    Parameters
    ----------
    points, normals : (M, 3) float64 arrays
        Working points [m] and unit normals oriented towards the sensor.
    nbrs, sqdist : (M, k) arrays
        Nearest neighbours and their squared distances [m^2].
    patches : (M,) int64 array
        Smooth patch of every point.
    max_edge : float
        Longest link [m].
    step : (M,) float64 array
        Largest step [m] within one surface at each point.
    min_piece : int
        A piece of fewer points, all of them ``noisy``, is no face of its own (e.g.
        ``min_face_points``): it stays with the piece of its old patch it has the most
        links to (:func:`_rejoin_shreds`).
    noisy : (M,) bool array, optional
        Points whose ``step`` is set by their noise (not by a fixed floor); default none.
    parallel_cos : float
        Normals of parallel surfaces agree within this cosine (:func:`_step_free`).

    Returns
    -------
    (M,) int64 array
        New patch of every point: connected pieces of the old patches.
    """
    m, k = nbrs.shape
    i = np.repeat(np.arange(m), k)
    j = nbrs.ravel()
    same = (patches[i] == patches[j]) & (sqdist.ravel() <= max_edge * max_edge)
    keep = same.copy()
    i, j = i[same], j[same]
    keep[same] = _step_free(points, normals, i, j, step, parallel_cos)[2]
    _, comp = link_components(nbrs, keep.reshape(m, k))
    if min_piece > 1 and noisy is not None and noisy.any():
        comp = _rejoin_shreds(comp, i, j, min_piece, noisy)
    return comp.astype(np.int64)


def _rejoin_shreds(comp: NDArray[np.int64], i: NDArray[np.int64], j: NDArray[np.int64],
                   min_piece: int, noisy: NDArray[np.bool_]) -> NDArray[np.int64]:
    """Give every noisy piece smaller than ``min_piece`` points to the piece it links to most.

    The step test of a link is a test against the noise, so on a sparse or noisy surface
    it cuts some links of one face; a point or two whose links all failed it fall off as
    a piece of their own (on the room scan's cabinet, 4-6 m away, its narrow side face
    seen at grazing incidence fell apart into pieces of 1-5 points and the cabinet lost
    it). A piece smaller than the smallest face whose points' steps are all set by their
    noise is no evidence of a second surface, so it returns to the neighbouring piece of
    its old patch it has the most links to, the step ignored. Real faces beyond a step are
    larger and stay apart, and so does a small piece where the noise is below the fixed
    step (a strip of a box's top along the crease under a box stacked on it, noise-free:
    a real surface, not a chip).

    Parameters
    ----------
    comp : (M,) int64 array
        Piece of every point (connected components after the cut).
    i, j : (L,) int64 arrays
        The links within the old patches (before the step test).
    min_piece : int
    noisy : (M,) bool array
        Points whose step is set by their noise; only pieces of such points rejoin.

    Returns
    -------
    (M,) int64 array
        Piece of every point (ids of ``comp``; one pass, a shred's partner keeps its own).
    """
    n = int(comp.max()) + 1
    size = np.bincount(comp, minlength=n)
    quiet = np.bincount(comp, weights=~noisy, minlength=n) > 0
    shred = (size < min_piece) & ~quiet
    if not shred.any():
        return comp
    from_shred = shred[comp][i]
    ci, cj = comp[i[from_shred]], comp[j[from_shred]]
    ok = ci != cj
    key, links = np.unique(ci[ok] * n + cj[ok], return_counts=True)
    if not len(key):
        return comp
    src, partner = key // n, key % n
    order = np.lexsort((links, src))  # per shred, the partner with most links comes last
    src, partner = src[order], partner[order]
    last = np.append(src[1:] != src[:-1], True)
    target = np.arange(n)
    target[src[last]] = partner[last]
    return target[comp]



def _split_levels(points: NDArray[np.float64], normals: NDArray[np.float64],
                  nbrs: NDArray[np.int64], sqdist: NDArray[np.float64],
                  patches: NDArray[np.int64], max_edge: float, noise_w: NDArray[np.float64],
                  floor: float, min_points: int, angle: float
                  ) -> tuple[NDArray[np.int64], list[tuple[int, int]]]:
    """Split flat patches that are two parallel surfaces at different heights.

    Two touching objects whose flat tops differ by a few millimetres (a can's top 3 mm
    above a box's beside it) grow into one patch: the working points along the contact
    average both heights, so each link crosses only part of the step and passes
    :func:`_step_free`. Over the whole patch the step shows. Each flat patch (most of its
    normals within ``angle`` [rad] of their mean) of at least twice ``min_points`` points
    is fitted with two levels: one tilted plane with two offsets, each point on the level
    nearer to the mean height of its neighbours (:func:`_level_split`). The split stands
    when both levels hold ``min_points`` points; their heights, measured on every other
    point of the patch with the levels found from the others (so that the noise that
    chose a point's level does not raise its height), differ by more than the step
    ``floor`` [m] and by :data:`LEVEL_SIGMAS` standard errors; the levels lie side by side
    as two regions (few links between them, :data:`LEVEL_MIXING`; neither's centre within
    the other's outline: the rim of one face, rounded down by the noise and the edge,
    surrounds it); and the links across their border rise, at their median, beyond the
    step floor and beyond :data:`LEVEL_SIGMAS` standard errors of that median under the
    border points' noise ``noise_w`` [m] (one vote per :data:`BORDER_STRIP_POINTS` border
    points, as for a crease).

    Returns
    -------
    patches : (M,) int64 array
        The patches, each split one's upper or lower level under a new id.
    stepped : list of (int, int)
        The two patches of each split: their border is a step, never joined.
    """
    m, k = nbrs.shape
    n_p = int(patches.max()) + 1
    sizes = np.bincount(patches, minlength=n_p)
    candidates = np.flatnonzero(sizes >= 2 * min_points)
    if not len(candidates):
        return patches, []
    order = np.argsort(patches, kind="stable")
    start = np.cumsum(sizes) - sizes
    within = sqdist <= max_edge * max_edge
    local = np.full(m, -1, dtype=np.int64)  # -1 outside the patch at hand (reset after it)
    out = patches.copy()
    stepped: list[tuple[int, int]] = []
    for pid in candidates.tolist():
        idx = order[start[pid]:start[pid] + sizes[pid]]
        level = _level_split(points[idx], normals[idx], nbrs[idx], within[idx], idx, local,
                             noise_w[idx], floor, min_points, angle)
        if level is not None:
            out[idx[level]] = n_p + len(stepped)
            stepped.append((pid, n_p + len(stepped)))
    return out, stepped


def _level_split(p: NDArray[np.float64], nr: NDArray[np.float64], nb: NDArray[np.int64],
                 within: NDArray[np.bool_], idx: NDArray[np.int64], local: NDArray[np.int64],
                 noise: NDArray[np.float64], floor: float, min_points: int, angle: float
                 ) -> NDArray[np.bool_] | None:
    """Return the upper level (bool per point) of one patch's two levels, or None.

    ``p``, ``nr`` (L, 3): the patch's points [m] and normals; ``nb``, ``within`` (L, k):
    their neighbour lists (indices into the M working points) and which links are short
    enough; ``idx`` (L,): the points' working indices; ``local`` (M,): -1 everywhere (used
    for the patch's local indices and left as it was); ``noise`` (L,) [m]. See
    :func:`_split_levels`.
    """
    mean = nr.sum(axis=0)
    mean /= max(float(np.linalg.norm(mean)), 1e-12)
    if np.median(np.abs(nr @ mean)) < math.cos(angle):
        return None  # not flat: its normals turn
    u, v = perpendicular_basis(mean)
    q = p - p.mean(axis=0)
    xyz = np.column_stack([q @ u, q @ v, q @ mean])
    local[idx] = np.arange(len(idx))
    ln = local[nb]
    local[idx] = -1
    ok = (ln >= 0) & within & (ln != np.arange(len(idx))[:, None])
    half = np.arange(len(idx)) % 2 == 0  # the levels are found from this half alone
    found = _two_levels(xyz, ln, ok, half)
    if found is None:
        return None
    upper, flat = found
    n_up = int(upper.sum())
    if n_up < min_points or len(upper) - n_up < min_points:
        return None
    delta = _held_out_step(xyz, upper, ~half, floor)
    if delta is None or not _side_by_side(xyz[:, :2], upper, ln, ok):
        return None
    # The step along the border: the links from the lower level to the upper one.
    ii, jj = np.nonzero(ok & upper[np.maximum(ln, 0)] & ~upper[:, None])
    if len(ii) < 3:
        return None
    rise = float(np.median(flat[ln[ii, jj]] - flat[ii]))
    votes = max(len(np.unique(ii)) / BORDER_STRIP_POINTS, 1.0)
    bound = max(floor, LEVEL_SIGMAS * MEDIAN_STANDARD_ERROR * math.sqrt(2.0)
                * float(np.median(noise[ii])) / math.sqrt(votes))
    if np.sign(rise) != np.sign(delta) or abs(rise) <= bound:
        return None
    return upper


def _two_levels(xyz: NDArray[np.float64], ln: NDArray[np.int64], ok: NDArray[np.bool_],
                half: NDArray[np.bool_]
                ) -> tuple[NDArray[np.bool_], NDArray[np.float64]] | None:
    """Return a patch's upper level and heights above its tilted plane, found from ``half``.

    ``xyz`` (L, 3): in-plane coordinates and height [m]; ``ln``, ``ok`` (L, k): the patch's
    neighbour lists (local indices) and the links used. Each point goes to the level
    nearer the mean height of its neighbours in ``half``; the tilted plane with the two
    offsets is fitted to ``half`` alone. None when one level is empty.
    """
    x, y, z = xyz.T
    safe = np.maximum(ln, 0)
    from_half = ok & half[safe]
    count = np.maximum(from_half.sum(axis=1), 1)

    def around(val: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.where(from_half, val[safe], 0.0).sum(axis=1) / count

    q1, q3 = np.percentile(z, [25, 75])
    upper = around(z) > 0.5 * (q1 + q3)
    flat = z
    # The design matrix of the plane with two offsets on ``half``: x, y, lower, upper.
    design = np.zeros((int(half.sum()), 4))
    design[:, 0], design[:, 1], z_half = x[half], y[half], z[half]
    for _ in range(LEVEL_ITERATIONS):
        on_top = upper[half]
        if on_top.all() or not on_top.any():
            return None
        design[:, 2], design[:, 3] = ~on_top, on_top
        coef = np.linalg.lstsq(design, z_half, rcond=None)[0]
        flat = z - coef[0] * x - coef[1] * y
        heights = around(flat)
        new = np.abs(heights - coef[3]) < np.abs(heights - coef[2])
        if (new == upper).all():
            break
        upper = new
    return upper, flat


def _held_out_step(xyz: NDArray[np.float64], upper: NDArray[np.bool_],
                   test: NDArray[np.bool_], floor: float) -> float | None:
    """Return the height of the upper level over the lower [m] on the ``test`` points, or None.

    The tilted plane and two offsets are fitted to the ``test`` points alone (their levels
    were chosen without their own heights); None unless the difference exceeds ``floor``
    and :data:`LEVEL_SIGMAS` of its standard error.
    """
    if (test & upper).sum() < 3 or (test & ~upper).sum() < 3:
        return None
    x, y, z = xyz[test].T
    up = upper[test]
    design = np.column_stack([x, y, ~up, up]).astype(np.float64)
    coef, *_ = np.linalg.lstsq(design, z, rcond=None)
    inv = np.linalg.pinv(design.T @ design)
    delta = float(coef[3] - coef[2])
    se = robust_sigma(z - design @ coef) * math.sqrt(
        max(float(inv[2, 2] + inv[3, 3] - 2.0 * inv[2, 3]), 0.0))
    return delta if abs(delta) > max(floor, LEVEL_SIGMAS * se) else None


def _side_by_side(xy: NDArray[np.float64], upper: NDArray[np.bool_], ln: NDArray[np.int64],
                  ok: NDArray[np.bool_]) -> bool:
    """Whether two levels lie side by side, as two objects' faces do.

    Few of the links ``ln``/``ok`` join them (at most :data:`LEVEL_MIXING` of the share
    levels drawn at random in the same proportions would give: the noise interleaves
    such levels), and neither level's centre lies within the other's outline in ``xy``
    (a face's rim, rounded down by the noise and the edge, surrounds it).
    """
    share = float(np.mean(upper))
    cross = float(np.mean((upper[np.maximum(ln, 0)] != upper[:, None])[ok]))
    if cross > LEVEL_MIXING * 2.0 * share * (1.0 - share):
        return False
    for inner, outer in ((upper, ~upper), (~upper, upper)):
        try:
            if Delaunay(xy[outer]).find_simplex(xy[inner].mean(axis=0)) >= 0:
                return False
        except QhullError:
            return False
    return True

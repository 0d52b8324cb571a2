"""Points on every link of the arm, and how far any of them travels during a stop.

ISO/TS 15066's S_s is the distance the robot travels while it stops, and the part of the arm
nearest a person is not always the tool: an elbow swinging out can travel farther than the
flange. This module samples points on each moving link, in the frame of the joint that moves
it, and follows them over a stop.

**Where the points come from.** The links' collision geometry of the robot's URDF, read by
Pinocchio (``buildGeomFromUrdf``, the same file :func:`vtm_pin.physics.robot.load_robot` built the
model from; ``package://`` paths are searched in the folders above the URDF, which holds for
example-robot-data, and in ``ROS_PACKAGE_PATH``). For each link the points are the **vertices of
the convex hull** of its shapes: meshes (read with ``trimesh``, scaled as the URDF says) and
primitives (a box's corners; cylinders, cones, spheres, capsules and ellipsoids as polygons of
:data:`ROUND` points per circle, inscribed, so the true surface bulges out by at most
r (1 - cos(pi / ROUND)), 0.5 % of the radius). Hull vertices suffice: for one rigid link moved
from one placement to another, the displacement |R p + t - (R0 p + t0)| is a convex function
of the body-fixed point p, so over a convex body it is largest at a vertex of the hull. A link
with more hull vertices than ``per_link`` keeps ``per_link`` of them, chosen by farthest-point
sampling (deterministic, starting from the vertex farthest from the joint); the largest distance
from a dropped vertex to a kept point is :attr:`ArmPoints.spacing`, and since the displacement
is 2-Lipschitz in p, the true largest displacement of the hulls is at most the sampled one plus
2 x spacing.

Where the robot has no collision geometry (the URDF has no ``<collision>`` elements, a mesh
file is missing, the robot is a xacro file), the points lie on the **segments between
consecutive joint origins** (and from the last joint to the tool frame): a stick figure of the
arm, which says nothing of how thick the links are (the ``source`` field says which). In a
URDF with collision geometry, a moving link without any gets its segments (``note`` names it).

The tool frame's origin is always one of the points (the link named ``tool frame '<name>'``),
so the arm's largest displacement is never below the tool's (S_s). The base (geometry fixed to
the world) never moves and is left out; a payload is not sampled beyond the tool frame.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from ..files.model_cache import ModelCache
from . import arm_kernel, body_kernel
from .kinematics import (
    body_velocities,
    cross,
    joint_placements,
    kinematic_data,
    kinematics_key,
    numpy_chain,
)
from .robot import Robot

#: ``ArmPoints.source`` for points on the links' collision geometry.
GEOMETRY = "collision geometry"
#: ``ArmPoints.source`` for points on the stick figure of a robot without collision geometry.
SEGMENTS = "segments between joint origins (no collision geometry)"
#: Default most points per link.
PER_LINK = 100
#: Points per circle of a round primitive (cylinder, cone, sphere, capsule, ellipsoid).
ROUND = 32

_CACHE = ModelCache(16)


@dataclass(frozen=True)
class ArmPoints:
    """Points on the moving links of a robot, each fixed in the frame of its joint.

    Attributes:
        points: Positions in the frame of the joint that moves each point [m], shape (k, 3),
            ordered by joint.
        joints: The Pinocchio joint index of each point's frame, shape (k,).
        link: Index into ``links`` of each point, shape (k,).
        links: Link names (the last is ``tool frame '<name>'``: the tool frame's origin).
        source: :data:`GEOMETRY` or :data:`SEGMENTS`.
        note: Why the segments were used, or which links without collision elements got
            their segments in a robot that has some; empty otherwise.
        spacing: Largest distance from a dropped hull vertex to a kept point [m] (0 if no
            vertex was dropped): the sampled largest displacement is at most 2 x spacing
            short of the hulls'.
        per_link: Most points per link asked for.
    """

    points: np.ndarray
    joints: np.ndarray
    link: np.ndarray
    links: tuple[str, ...]
    source: str
    note: str
    spacing: float
    per_link: int

    @cached_property
    def groups(self) -> _Groups:
        """The points by joint (:class:`_Groups`), computed once."""
        used, starts, counts = np.unique(self.joints, return_index=True, return_counts=True)
        centers = np.empty((len(used), 3))
        radii = np.empty(len(used))
        for g, (start, count) in enumerate(zip(starts, counts, strict=True)):
            mine = self.points[start : start + count]
            centers[g] = (mine.min(axis=0) + mine.max(axis=0)) / 2.0
            radii[g] = np.max(np.linalg.norm(mine - centers[g], axis=1))
        rows = np.repeat(np.arange(len(used)), counts)
        for array in (used, starts, centers, radii, rows):
            array.flags.writeable = False
        consecutive = len(used) and np.all(np.diff(used) == 1)
        carry = slice(int(used[0]), int(used[-1]) + 1) if consecutive else used
        columns = np.ascontiguousarray(self.points.T)
        columns.flags.writeable = False
        return _Groups(used, starts, starts + counts, centers, radii, rows, carry, columns)


@dataclass(frozen=True)
class _Groups:
    """The points of an :class:`ArmPoints` by joint (they are ordered by joint).

    Attributes:
        joints: The joints that carry points, shape (m,).
        starts: The first point of each, shape (m,).
        stops: One past its last point, shape (m,).
        centers: The centre of each joint's points' bounding box, in its frame [m], (m, 3).
        radii: The largest distance of a joint's points from its centre [m], shape (m,).
        rows: Each point's group, shape (k,).
        carry: ``joints`` as an index of the joints' axis (a slice where consecutive).
        columns: The points by columns (x, y, z rows) [m], shape (3, k).
    """

    joints: np.ndarray
    starts: np.ndarray
    stops: np.ndarray
    centers: np.ndarray
    radii: np.ndarray
    rows: np.ndarray
    carry: slice | np.ndarray
    columns: np.ndarray


@dataclass(frozen=True)
class ArmDisplacement:
    """The largest displacement of any point of the arm over a trajectory.

    Attributes:
        distance: max over points and samples of |p(q_t) - p(q_0)| [m].
        index: The point that travels it (a row of :attr:`ArmPoints.points`).
        link: That point's link name.
        sample: The row of the trajectory where it is reached.
        swept: World positions of every point at every sample [m], shape (T, k, 3); None
            unless asked for.
    """

    distance: float
    index: int
    link: str
    sample: int
    swept: np.ndarray | None = None


def sample_arm_points(robot: Robot, per_link: int = PER_LINK) -> ArmPoints:
    """Points on each moving link of ``robot`` (see the module docstring), cached per model.

    Args:
        robot: The robot (a payload copy shares its robot's sample: the joints are the same).
        per_link: Most points per link, >= 2.

    Raises:
        ValueError: ``per_link`` < 2.
    """
    if per_link < 2:
        raise ValueError(f"per_link is {per_link}; at least 2 points per link are needed")

    def shared() -> ArmPoints:
        key = (robot.source, per_link, robot.tool_frame, kinematics_key(robot))
        return _CACHE.get(key, lambda: _sample(robot, per_link))

    return robot.cache.get(("arm_points", per_link), shared, kinematic=True)


def _sample(robot: Robot, per_link: int) -> ArmPoints:
    groups, note = _geometry_groups(robot)
    source = GEOMETRY if groups else SEGMENTS
    spacing = 0.0
    if groups:
        chosen = {}
        for name, (joint, cloud) in groups.items():
            kept, gap = _farthest_points(_hull(cloud), per_link)
            chosen[name] = (joint, kept)
            spacing = max(spacing, gap)
        # Moving links without collision elements get their segments (the tool frame aside).
        covered = {joint for joint, _ in chosen.values()}
        bare = {k: v for k, v in _segment_groups(robot, per_link).items() if v[0] not in covered}
        if bare:
            note = f"no collision geometry on {', '.join(bare)}: their segments are sampled"
        groups = {**chosen, **bare}
    else:
        groups = _segment_groups(robot, per_link)
    model = robot.model
    tool = model.frames[model.getFrameId(robot.tool_frame)]
    groups[f"tool frame '{robot.tool_frame}'"] = (
        int(tool.parentJoint),
        np.asarray(tool.placement.translation, dtype=float)[None],
    )
    groups = {name: (joint, cloud) for name, (joint, cloud) in groups.items() if joint > 0}
    links = tuple(groups)
    points = np.vstack([cloud for _, cloud in groups.values()])
    joints = np.concatenate([np.full(len(c), j, dtype=int) for j, c in groups.values()])
    link = np.repeat(np.arange(len(links)), [len(cloud) for _, cloud in groups.values()])
    order = np.argsort(joints, kind="stable")  # each joint's points together
    points, joints, link = points[order], joints[order], link[order]
    for array in (points, joints, link):
        array.flags.writeable = False
    return ArmPoints(points, joints, link, links, source, note, spacing, per_link)


def _geometry_groups(robot: Robot) -> tuple[dict[str, tuple[int, np.ndarray]], str]:
    """Per link: (joint index, hull candidates in the joint frame); and why none, if none."""
    path = Path(robot.source)
    if path.suffix.lower() != ".urdf" or not path.is_file():
        return {}, f"the robot's file {robot.source} is not a URDF file this module reads"
    try:
        geometry = pin.buildGeomFromUrdf(
            robot.model,
            str(path),
            pin.GeometryType.COLLISION,
            package_dirs=[str(d) for d in path.parents],
        )
    except Exception as exc:  # Pinocchio raises bare exceptions for missing meshes
        return {}, f"its collision geometry could not be loaded ({' '.join(str(exc).split())})"
    groups: dict[str, tuple[int, list[np.ndarray]]] = {}
    skipped = []
    for obj in geometry.geometryObjects:
        local = _shape_points(obj)
        if local is None:
            skipped.append(obj.name)
            continue
        name = str(robot.model.frames[obj.parentFrame].name)
        cloud = local @ obj.placement.rotation.T + obj.placement.translation
        groups.setdefault(name, (int(obj.parentJoint), []))[1].append(cloud)
    if not groups:
        why = "shapes this module cannot sample" if skipped else "no <collision> elements"
        return {}, f"the URDF has {why}"
    return {name: (joint, np.vstack(clouds)) for name, (joint, clouds) in groups.items()}, ""


def _shape_points(obj: pin.GeometryObject) -> np.ndarray | None:
    """Points whose hull is the shape, in the shape's own frame [m]; None if unknown."""
    shape = obj.geometry
    kind = type(shape).__name__
    mesh = str(obj.meshPath)
    if mesh and Path(mesh).is_file() and kind.startswith(("BVHModel", "Convex")):
        import trimesh

        loaded: Any = trimesh.load(mesh, force="mesh")
        return np.array(loaded.vertices, dtype=np.float64) * np.asarray(obj.meshScale)
    circle = np.linspace(0.0, 2.0 * math.pi, ROUND, endpoint=False)
    ring = np.column_stack([np.cos(circle), np.sin(circle), np.zeros(ROUND)])
    if kind == "Box":
        h = np.asarray(shape.halfSide, dtype=float)
        return np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * h
    up = np.array([0.0, 0.0, getattr(shape, "halfLength", 0.0)])  # half the axis [m]
    if kind == "Cylinder":
        return np.vstack([ring * shape.radius + up, ring * shape.radius - up])
    if kind == "Cone":
        return np.vstack([ring * shape.radius - up, up])
    if kind in ("Sphere", "Ellipsoid", "Capsule"):
        radii = np.asarray(shape.radii) if kind == "Ellipsoid" else np.full(3, shape.radius)
        ball = _sphere() * radii
        if kind != "Capsule":
            return ball
        return np.vstack([ball + up, ball - up])
    return None


def _sphere() -> np.ndarray:
    """ROUND^2 / 2 points on the unit sphere (a Fibonacci lattice)."""
    count = ROUND * ROUND // 2
    k = np.arange(count) + 0.5
    z = 1.0 - 2.0 * k / count
    phi = math.pi * (3.0 - math.sqrt(5.0)) * k
    r = np.sqrt(1.0 - z * z)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def _hull(cloud: np.ndarray) -> np.ndarray:
    """The vertices of the convex hull of ``cloud`` (all of it if it is flat or tiny)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        return np.asarray(cloud[ConvexHull(cloud).vertices])
    except (QhullError, ValueError):
        return np.unique(cloud, axis=0)


def _farthest_points(cloud: np.ndarray, count: int) -> tuple[np.ndarray, float]:
    """``count`` points of ``cloud`` by farthest-point sampling, and the covering gap [m].

    Starts from the point farthest from the joint origin; the gap is the largest distance
    from a point of ``cloud`` to the nearest kept one (0 if all are kept).
    """
    if len(cloud) <= count:
        return cloud, 0.0
    chosen = [int(np.argmax(np.linalg.norm(cloud, axis=1)))]
    gap = np.linalg.norm(cloud - cloud[chosen[0]], axis=1)
    while len(chosen) < count:
        nxt = int(np.argmax(gap))
        chosen.append(nxt)
        gap = np.minimum(gap, np.linalg.norm(cloud - cloud[nxt], axis=1))
    return cloud[chosen], float(np.max(gap))


def _segment_groups(robot: Robot, per_link: int) -> dict[str, tuple[int, np.ndarray]]:
    """Per link: points on the segments from its joint's origin to its children's and the tool.

    A link with several children (or a child and the tool frame) shares ``per_link`` among
    its segments, at least 2 points (the ends) on each.
    """
    model = robot.model
    ends: dict[int, list[np.ndarray]] = {}
    for j in range(1, model.njoints):
        ends.setdefault(int(model.parents[j]), []).append(model.jointPlacements[j].translation)
    tool = model.frames[model.getFrameId(robot.tool_frame)]
    ends.setdefault(int(tool.parentJoint), []).append(tool.placement.translation)
    groups = {}
    for joint, tips in ends.items():
        if joint == 0:
            continue
        count = max(2, per_link // len(tips))
        s = np.linspace(0.0, 1.0, count)[:, None]
        cloud = np.vstack([s * np.asarray(tip, dtype=float)[None] for tip in tips])
        groups[_link_name(model, joint)] = (joint, cloud)
    return groups


def _link_name(model: pin.Model, joint: int) -> str:
    """The URDF link moved by ``joint`` (its body frame), else the joint's name."""
    for frame in model.frames:
        if frame.parentJoint == joint and frame.type == pin.FrameType.BODY:
            return str(frame.name)
    return str(model.names[joint])


def point_positions(robot: Robot, points: ArmPoints, q: np.ndarray) -> np.ndarray:
    """World positions of the points at configuration ``q`` [rad], shape (k, 3) [m]."""
    R, p = joint_placements(robot, np.asarray(q, dtype=float)[None])
    return _place(points, R, p)[:, :, 0]


#: Relative slack on the bound of a joint's points' displacement (:func:`max_displacement`),
#: far above its round-off (~1e-15): a joint and sample are skipped only when surely below.
BOUND_SLACK = 1e-9
#: And an absolute one [m], for displacements at the round-off of the placements (~1e-16 m).
BOUND_FLOOR = 1e-12
#: Samples whose point displacements are formed at once (memory: CHUNK x k x 3 floats).
CHUNK = 256


def _place(points: ArmPoints, R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Where the points go under the joints' placements: R p_i + p, shape (k, 3, T) [m].

    One matrix product per joint over all T samples at once (points by rows, axes and
    samples by columns), each axis's samples contiguous.

    Args:
        points: The points.
        R: Rotations of the joints' frames at T samples, shape (T, njoints, 3, 3).
        p: Their origins [m], shape (T, njoints, 3).
    """
    count = len(R)
    out = np.empty((len(points.points), 3 * count))
    groups = points.groups
    for j, start, stop in zip(groups.joints, groups.starts, groups.stops, strict=True):
        mine = slice(int(start), int(stop))
        columns = R[:, j].transpose(2, 1, 0).reshape(3, 3 * count)  # [b, a T + t] = R[t, a, b]
        np.matmul(points.points[mine], columns, out=out[mine])
        out[mine] += p[:, j].T.reshape(-1)
    return out.reshape(len(points.points), 3, count)


def max_displacement(
    robot: Robot,
    points: ArmPoints,
    q_traj: np.ndarray,
    swept: bool = True,
    placements: tuple[np.ndarray, np.ndarray] | None = None,
) -> ArmDisplacement:
    """The largest straight-line displacement of any point from where it was at ``q_traj[0]``.

    A point p_i fixed to joint j moves by (R_t - R_0) p_i + (o_t - o_0) from sample 0 to
    sample t (R, o: the joint's placements); the squared lengths are compared, and the
    square root taken of the largest (on a tie, the first sample, then the first point).

    Only the joints and samples that may hold the largest are formed: the points of joint j
    lie within r_j of a centre c_j, so at sample t none moves farther than
    |(R_t - R_0) c_j + o_t - o_0| + ||R_t - R_0||_2 r_j; the joint's points are formed at the
    samples where this bound reaches the largest displacement found so far (first at the
    sample and joint of the largest bound), all others are below it.

    Args:
        robot: The robot.
        points: Its points (:func:`sample_arm_points`).
        q_traj: Configurations [rad], shape (T, n), T >= 1; the first is the reference (the
            stop signal).
        swept: Whether to return every point's positions (for a 3D drawing; T x k x 3
            floats).
        placements: The joints' placements at ``q_traj`` (``joint_placements(robot,
            q_traj)``), if they are at hand.
    """
    qs = np.atleast_2d(np.asarray(q_traj, dtype=float))
    R, p = joint_placements(robot, qs) if placements is None else placements
    groups = points.groups
    carry = groups.carry
    turn = R[:, carry] - R[:1, carry]  # (T, m, 3, 3)
    shift = p[:, carry] - p[:1, carry]  # (T, m, 3)
    bound = _bounds(points, turn, shift)
    t, g = np.unravel_index(int(np.argmax(bound)), bound.shape)
    best, index, sample = 0.0, 0, 0
    # The likeliest sample of the likeliest joint first, a high bar for the others; then each
    # joint (likeliest first) at the samples where its bound reaches the bar.
    order = [int(h) for h in np.argsort(-np.max(bound, axis=0), kind="stable")]
    for group, first in ((int(g), int(t)), *((h, None) for h in order)):
        if first is None:
            rows = [int(r) for r in np.flatnonzero(bound[:, group] >= math.sqrt(best))]
        else:
            rows = [first]
        for chunk in range(0, len(rows), CHUNK):
            some = rows[chunk : chunk + CHUNK]
            largest, k, r = _largest(points, group, turn[some, group], shift[some, group])
            if largest > best or (largest == best and (some[r], k) < (sample, index)):
                best, index, sample = largest, k, some[r]
    link = points.links[int(points.link[index])]
    kept = np.ascontiguousarray(_place(points, R, p).transpose(2, 0, 1)) if swept else None
    return ArmDisplacement(math.sqrt(best), index, link, sample, kept)


def max_displacements(
    points: ArmPoints, placements: Sequence[tuple[np.ndarray, np.ndarray]]
) -> list[ArmDisplacement]:
    """:func:`max_displacement` of many trajectories at once, each from its own first sample.

    The same displacements, bounds and ties as trajectory by trajectory (``swept=False``), as
    array operations over all their samples: the bounds of every joint at every sample; each
    trajectory's points at the sample and joint of its largest bound, a bar; then, at once
    for each joint, its points at every sample (of any trajectory) whose bound reaches that
    trajectory's bar. Those include every sample and joint that the one-by-one search forms
    whose displacement can reach its result, so the largest is the same, found first at the
    same sample and point.

    Args:
        points: The points (:func:`sample_arm_points`) of the trajectories' robot.
        placements: Per trajectory, the joints' placements ``(R, p)`` at its T >= 1 samples
            (:func:`~vtm_pin.physics.kinematics.joint_placements`), shapes (T, njoints, 3, 3)
            and (T, njoints, 3) [m].
    """
    counts = np.array([len(p) for _, p in placements])
    firsts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int)
    carry = points.groups.carry
    R = np.concatenate([r[:, carry] for r, _ in placements])
    o = np.concatenate([p[:, carry] for _, p in placements])
    if arm_kernel.runs():
        try:
            found = arm_kernel.largest_displacements(
                R, o, firsts, counts, points.groups, points.points, BOUND_SLACK, BOUND_FLOOR
            )
        except body_kernel.failures() as exc:  # Numba cannot run here: NumPy from now on
            body_kernel.fall_back(exc)
        else:
            return [_displacement(points, *best) for best in zip(*found, strict=True)]
    owner = np.repeat(np.arange(len(counts)), counts)  # each sample's trajectory
    turn = R - R[firsts][owner]  # (S, m, 3, 3): each sample against its trajectory's first
    shift = o - o[firsts][owner]
    bound = _bounds(points, turn, shift)
    top = [int(np.argmax(bound[a:b])) for a, b in zip(firsts, firsts + counts, strict=True)]
    sample, group = np.divmod(np.array(top, dtype=int), bound.shape[1])
    sample += firsts
    bar = _exact(points, turn, shift, sample, group)[0]
    sample, group = np.nonzero(bound >= np.sqrt(bar)[owner][:, None])
    value, point = _exact(points, turn, shift, sample, group)
    # per trajectory: the largest, then the first sample, then the first point
    order = np.lexsort((point, sample, -value, owner[sample]))
    _, first = np.unique(owner[sample][order], return_index=True)
    best = order[first]
    return [
        _displacement(points, value[k], point[k], sample[k] - firsts[c]) for c, k in enumerate(best)
    ]


def _displacement(points: ArmPoints, squared: float, index: int, row: int) -> ArmDisplacement:
    """The :class:`ArmDisplacement` of a largest squared displacement [m^2], point and sample.

    Point 0 at sample 0 where nothing moves.
    """
    if not squared > 0.0:
        index, row = 0, 0
    link = points.links[int(points.link[int(index)])]
    return ArmDisplacement(math.sqrt(float(squared)), int(index), link, int(row))


def _bounds(points: ArmPoints, turn: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """Upper bounds [m] of each joint's points' displacements at each sample, shape (T, m).

    ``turn`` = R_t - R_0 and ``shift`` = o_t - o_0 of the joints at T samples, shapes
    (T, m, 3, 3) and (T, m, 3) (see :func:`max_displacement`).
    """
    groups = points.groups
    middle = np.einsum("tgab,gb->tga", turn, groups.centers) + shift
    bound = np.sqrt(np.einsum("tga,tga->tg", middle, middle))
    # ||R_t - R_0||_2 = ||R_t - R_0||_F / sqrt(2): R_0^T R_t - I, a rotation by theta less
    # the identity, has the singular values 2 sin(theta / 2) twice and 0
    bound += np.sqrt(np.einsum("tgab,tgab->tg", turn, turn) / 2.0) * groups.radii
    out: np.ndarray = bound * (1.0 + BOUND_SLACK) + BOUND_FLOOR
    return out


def _exact(
    points: ArmPoints, turn: np.ndarray, shift: np.ndarray, sample: np.ndarray, group: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The largest squared displacement [m^2] of joint ``group[i]``'s points at ``sample[i]``.

    Returns:
        ``(squared, point)`` per pair: the largest and its point (the first on a tie).
    """
    squared = np.empty(len(sample))
    point = np.empty(len(sample), dtype=int)
    groups = points.groups
    for g in np.unique(group):
        mine = np.flatnonzero(group == g)
        start, stop = int(groups.starts[g]), int(groups.stops[g])
        rows = sample[mine]
        for chunk in range(0, len(rows), CHUNK):
            some = rows[chunk : chunk + CHUNK]
            each = _squared(points.points[start:stop], turn[some, g], shift[some, g])
            best = np.argmax(each, axis=0)  # the first point of the largest, per sample
            squared[mine[chunk : chunk + CHUNK]] = each[best, np.arange(len(some))]
            point[mine[chunk : chunk + CHUNK]] = start + best
    return squared, point


def _squared(points: np.ndarray, turn: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """Squared displacements |turn_r p + shift_r|^2 [m^2] of points, shape (k, s).

    ``points`` [m], shape (k, 3); ``turn``, shape (s, 3, 3), and ``shift`` [m], shape (s, 3).
    """
    count = len(turn)
    columns = turn.transpose(2, 1, 0).reshape(3, 3 * count)  # [b, a s + r] = turn[r, a, b]
    step = (points @ columns + shift.T.reshape(-1)).reshape(-1, 3, count)
    out: np.ndarray = np.einsum("kir,kir->kr", step, step)
    return out


def _largest(
    points: ArmPoints, group: int, turn: np.ndarray, shift: np.ndarray
) -> tuple[float, int, int]:
    """The largest squared displacement [m^2] of one joint's points over some samples.

    Args:
        points: The points.
        group: The joint's group (:attr:`ArmPoints.groups`).
        turn: R_t - R_0 of the joint at those samples, shape (s, 3, 3).
        shift: o_t - o_0 at those samples [m], shape (s, 3).

    Returns:
        ``(squared, point, row)``: the largest, the point (a row of :attr:`ArmPoints.points`)
        and the sample (a row of ``turn``) where it is reached, the first sample and then the
        first point on a tie.
    """
    groups = points.groups
    start, stop = int(groups.starts[group]), int(groups.stops[group])
    squared = _squared(points.points[start:stop], turn, shift)
    first = int(np.argmax(squared.T))  # by sample, then by point: the first hit of a tie
    r, k = divmod(first, len(squared))
    return float(squared[k, r]), start + k, r


def fastest_point_speeds(
    robot: Robot, points: ArmPoints, placements: tuple[np.ndarray, np.ndarray], v: np.ndarray
) -> np.ndarray:
    """The fastest point's speed [m/s] at each of T states, shape (T,).

    :func:`point_speeds`' largest, at many states at once from the joints' placements
    ``(R, p)`` at them (:func:`~vtm_pin.physics.kinematics.joint_placements`) and the rates
    ``v`` [rad/s or m/s], shape (T, nv): a point at R_j p_i + o_j of joint j's body moves at
    v_j + omega_j x (R_j p_i) (:func:`~vtm_pin.physics.kinematics.body_velocities`).

    Raises:
        ValueError: The model has a joint type the NumPy kinematics do not take.
    """
    chain = numpy_chain(robot)
    R, p = placements
    omega, velocity = body_velocities(chain, R, p, np.asarray(v, dtype=float))
    groups = points.groups
    if arm_kernel.runs():
        try:
            return arm_kernel.fastest_speeds(R, omega, velocity, groups, points.points)
        except body_kernel.failures() as exc:  # Numba cannot run here: NumPy from now on
            body_kernel.fall_back(exc)
    out = np.zeros(len(R))
    for j, start, stop in zip(groups.joints, groups.starts, groups.stops, strict=True):
        arms = points.points[start:stop] @ R[:, j].transpose(0, 2, 1)  # (T, k, 3): R_j p_i
        moving = velocity[:, j, None] + cross(omega[:, j, None], arms)
        fastest = np.sqrt(np.max(np.einsum("tki,tki->tk", moving, moving), axis=1))
        np.maximum(out, fastest, out=out)
    return out


def point_speeds(robot: Robot, points: ArmPoints, q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The speed of each point at (q [rad], v [rad/s]), shape (k,) [m/s].

    A point p fixed in joint j's frame moves at v_j + omega_j x p, the joint's spatial velocity
    in its own frame (Pinocchio's ``data.v``); a rotation to world axes keeps its length.
    """
    model = robot.model
    data = kinematic_data(robot)
    pin.forwardKinematics(model, data, np.asarray(q, dtype=float), np.asarray(v, dtype=float))
    groups = points.groups
    motions = [data.v[int(joint)] for joint in groups.joints]
    linear = np.array([m.linear for m in motions]).T[:, groups.rows]  # (3, k): each point's
    angular = np.array([m.angular for m in motions]).T[:, groups.rows]
    (l0, l1, l2), (a0, a1, a2), (p0, p1, p2) = linear, angular, groups.columns
    # v + omega x p (np.cross's products), and its length as np.linalg.norm(..., axis=1) adds
    x0 = l0 + (a1 * p2 - a2 * p1)
    x1 = l1 + (a2 * p0 - a0 * p2)
    x2 = l2 + (a0 * p1 - a1 * p0)
    return np.sqrt((x0 * x0 + x1 * x1) + x2 * x2)

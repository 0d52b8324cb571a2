"""Pictures of a robot: its links as segments at one or more configurations, and tool paths.

The skeleton comes from Pinocchio's forward kinematics of the robot's URDF model: a segment
joins each joint to its parent joint (the first to the world origin), and each last joint of a
branch to the farthest frame it carries (the tool frame on the tool's branch). Planar robots,
whose points all lie in one vertical plane, are drawn in 2D; others in 3D.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from ..core.results import SimulationResult
from ..physics.kinematics import compute_tool_positions
from ..physics.robot import Robot

#: Spread [m] below which a world axis counts as constant and a robot as planar.
PLANAR_TOLERANCE = 1e-9
_AXES = {"x": 0, "y": 1, "z": 2}
_PLANES = ("xz", "yz", "xy")


@dataclass(frozen=True)
class Skeleton:
    """A robot's links as segments at one configuration.

    Attributes:
        joints: Origins of the moving joints [m], shape (n, 3), in model order.
        segments: Link segments [m], shape (s, 2, 3): start and end point of each.
        ground: Segments from the world origin to the joints fixed on it [m], shape (g, 2, 3).
        tool: Position of the tool frame [m], shape (3,).
    """

    joints: np.ndarray
    segments: np.ndarray
    ground: np.ndarray
    tool: np.ndarray


def compute_skeleton(robot: Robot, q: np.ndarray, tool_frame: str | None = None) -> Skeleton:
    """Joint origins, link segments and tool position at configuration ``q`` [rad].

    Args:
        robot: The robot.
        q: Joint positions [rad], shape (n,).
        tool_frame: Frame that ends the tool's branch; the robot's tool frame by default.
    """
    model = robot.model
    data = model.createData()
    pin.forwardKinematics(model, data, np.asarray(q, dtype=float))
    pin.updateFramePlacements(model, data)
    origin = [data.oMi[i].translation.copy() for i in range(model.njoints)]
    tool_id = model.getFrameId(tool_frame or robot.tool_frame)
    tool = data.oMf[tool_id].translation.copy()
    ground = [(origin[0], origin[i]) for i in range(1, model.njoints) if model.parents[i] == 0]
    segments = [
        (origin[model.parents[i]], origin[i])
        for i in range(1, model.njoints)
        if model.parents[i] != 0
    ]
    has_child = {int(model.parents[i]) for i in range(1, model.njoints)}
    for i in range(1, model.njoints):
        if i in has_child:
            continue
        if int(model.frames[tool_id].parentJoint) == i:
            end = tool
        else:
            carried = [
                data.oMf[f].translation
                for f, frame in enumerate(model.frames)
                if int(frame.parentJoint) == i
            ]
            end = max(carried, key=lambda p: float(np.linalg.norm(p - origin[i])))
        if np.linalg.norm(end - origin[i]) > 1e-6:
            segments.append((origin[i], end.copy()))
    return Skeleton(
        np.array(origin[1:]),
        np.array(segments).reshape(-1, 2, 3),
        np.array(ground).reshape(-1, 2, 3),
        tool,
    )


def planar_view(points: np.ndarray) -> str | None:
    """``"xz"``, ``"yz"`` or ``"xy"`` if every point [m] lies in a plane normal to a world axis."""
    spread = np.ptp(points.reshape(-1, 3), axis=0)
    for view, normal in zip(_PLANES, (1, 0, 2), strict=True):
        if spread[normal] < PLANAR_TOLERANCE:
            return view
    return None


def draw_robot(
    robot: Robot,
    q: np.ndarray,
    *,
    ax: Axes | None = None,
    color: str = "C0",
    label: str | None = None,
    alpha: Sequence[float] | None = None,
    path: np.ndarray | None = None,
    tool_frame: str | None = None,
    view: str = "auto",
) -> Figure:
    """Draw the robot at one or more configurations, overlaid, and optionally its tool path.

    Links are segments, joints circles, the tool frame a cross; the base (world origin) is a
    black square. Poses are overlaid with rising opacity, the last one opaque.

    Args:
        robot: The robot.
        q: Joint positions [rad], shape (n,) or (k, n), one row per pose.
        ax: Axes to draw into (2D, or 3D for ``view="3d"``); a new figure if None.
        color: Matplotlib colour of this group of poses.
        label: Legend entry of the group.
        alpha: Opacity per pose; from 0.25 up to 1 by default.
        path: Configurations (m, n) [rad] whose tool-frame path is drawn as a thin line.
        tool_frame: Frame marked as the tool; the robot's tool frame by default.
        view: ``"auto"`` (2D for a planar robot, else 3D), ``"3d"``, ``"xz"``, ``"yz"`` or
            ``"xy"``. With ``ax`` given, 3D axes draw in 3D and 2D axes in this plane
            (``"auto"``: the robot's plane).

    Returns:
        The figure drawn into.

    Raises:
        ValueError: ``view`` is not one of the names above, or a non-planar robot is to be
            drawn into 2D axes with ``view="auto"``.
    """
    poses = np.atleast_2d(np.asarray(q, dtype=float))
    skeletons = [compute_skeleton(robot, qi, tool_frame) for qi in poses]
    tool_path = None if path is None else compute_tool_positions(robot, path, tool_frame)
    points = [np.vstack([s.segments, s.ground]).reshape(-1, 3) for s in skeletons]
    if tool_path is not None:
        points.append(tool_path)
    if view == "auto":
        view = _auto_view(robot, points)
    if ax is None:
        ax = _new_axes(view)
    fig = ax.get_figure()
    assert isinstance(fig, Figure)
    if ax.name == "3d":
        dims = [0, 1, 2]
    elif view in _PLANES:
        dims = [_AXES[c] for c in view]
    else:
        raise ValueError(f"{robot.name} is not planar: draw it into 3D axes")
    opacity = alpha if alpha is not None else np.linspace(0.25, 1.0, len(poses))
    for k, (skeleton, a) in enumerate(zip(skeletons, opacity, strict=True)):
        last = k == len(poses) - 1
        for start, end in skeleton.segments:
            ax.plot(*np.array([start, end])[:, dims].T, color=color, lw=3, alpha=a)
        for start, end in skeleton.ground:
            ax.plot(*np.array([start, end])[:, dims].T, color="k", lw=2, alpha=0.5)
        ax.plot(*skeleton.joints[:, dims].T, "o", color=color, mfc="white", ms=6, alpha=a)
        ax.plot(*skeleton.tool[dims, None], "x", color=color, ms=8, mew=2, alpha=a)
        if last and label is not None:
            ax.plot([], [], "-o", color=color, mfc="white", lw=3, label=label)
    if tool_path is not None:
        ax.plot(*tool_path[:, dims].T, color=color, lw=1, alpha=0.8)
    ax.plot(*np.zeros((len(dims), 1)), "s", color="k", ms=8)
    _label_axes(ax)
    return fig


def plot_poses(
    robot: Robot,
    results: Mapping[str, SimulationResult],
    tool_frame: str | None = None,
    view: str = "auto",
) -> Figure:
    """Initial pose, poses at the events and final pose per transition rule, with tool paths.

    Args:
        robot: The robot simulated.
        results: Simulation per rule name (they share the initial state).
        tool_frame: Frame whose path is drawn; the robot's tool frame by default.
        view: As in :func:`draw_robot`.
    """
    first = next(iter(results.values()))
    if view == "auto":
        view = _auto_view(robot, [])
    ax = _new_axes(view)
    fig = ax.get_figure()
    assert isinstance(fig, Figure)
    draw_robot(robot, first.q[0], ax=ax, color="0.3", label="initial", alpha=[0.6], view=view)
    for k, (name, result) in enumerate(results.items()):
        times = sorted({e.t for e in result.events if 0.0 < e.t < result.t[-1]})
        poses = result.q_at([*times, result.t[-1]])
        draw_robot(
            robot,
            poses,
            ax=ax,
            color=f"C{k}",
            label=f"{name}: final" + (" (fainter: at the events)" if times else ""),
            alpha=[0.3] * len(times) + [1.0],
            path=result.q,
            tool_frame=tool_frame,
            view=view,
        )
    ax.set_title(f"{robot.name}: poses, t = 0 to {first.t[-1]:g} s, and tool-frame paths")
    ax.legend(fontsize="small")
    return fig


def plot_snapshots(
    robot: Robot,
    results: Mapping[str, SimulationResult],
    times: Sequence[float],
    tool_frame: str | None = None,
) -> Figure:
    """One panel per transition rule: the robot at the given times [s], and its tool path.

    Poses get rising opacity in time order; each tool position is labelled with its time.
    Planar robots are drawn in their plane, others in 3D.
    """
    view = _auto_view(robot, [])
    fig = Figure(figsize=(5.5 * len(results), 5.5), layout="constrained")
    first: Axes | None = None
    for k, (name, result) in enumerate(results.items()):
        if view == "3d":
            ax = fig.add_subplot(1, len(results), k + 1, projection="3d")
        else:
            ax = fig.add_subplot(1, len(results), k + 1, sharex=first, sharey=first)
            _style_plane(ax, view, adjustable="box")  # shared axes cannot adjust limits
            first = first or ax
        poses = result.q_at(times)
        draw_robot(robot, poses, ax=ax, color=f"C{k}", path=result.q, view=view)
        dims = [0, 1, 2] if view == "3d" else [_AXES[c] for c in view]
        for t, qi in zip(times, poses, strict=True):
            tip = compute_skeleton(robot, qi, tool_frame).tool[dims]
            ax.text(*tip, f" t = {t:g} s", fontsize="small", color=f"C{k}")
        ax.set_title(f"{name}: t = {', '.join(f'{t:g}' for t in times)} s", fontsize="medium")
    return fig


def _auto_view(robot: Robot, points: list[np.ndarray]) -> str:
    """The robot's plane if it and ``points`` [m] stay in one, else ``"3d"``.

    Three random configurations join the given points, so that a spatial robot whose drawn
    poses happen to lie in a plane is still drawn in 3D; a robot that stays in a plane over
    them keeps its tool paths in it too, so paths need not be passed.
    """
    rng = np.random.default_rng(0)
    for _ in range(3):
        q = rng.uniform(-1.0, 1.0, robot.nv)
        skeleton = compute_skeleton(robot, q)
        points = [*points, np.vstack([skeleton.segments, skeleton.ground]).reshape(-1, 3)]
    return planar_view(np.vstack(points)) or "3d"


def _new_axes(view: str) -> Axes:
    if view != "3d" and view not in _PLANES:
        raise ValueError(f"view '{view}' is not one of auto, 3d, xy, xz, yz")
    fig = Figure(figsize=(7, 6), layout="constrained")
    if view == "3d":
        return fig.add_subplot(projection="3d")
    ax = fig.add_subplot()
    _style_plane(ax, view)
    return ax


def _style_plane(ax: Axes, view: str, adjustable: str = "datalim") -> None:
    ax.set_aspect("equal", adjustable=adjustable)  # type: ignore[arg-type]
    ax.grid(alpha=0.3)
    ax.set_xlabel(f"{view[0]} [m]")
    ax.set_ylabel(f"{view[1]} [m]")


def _label_axes(ax: Axes) -> None:
    """3D axes: label them and make a cube around everything drawn (equal scales)."""
    if ax.name != "3d":
        return
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")  # type: ignore[attr-defined]
    points = np.hstack([np.array(line.get_data_3d()) for line in ax.lines])  # type: ignore[attr-defined]
    low, high = points.min(axis=1), points.max(axis=1)
    centre, half = (low + high) / 2, max(float(np.max(high - low)) / 2, 1e-3) * 1.05
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)  # type: ignore[attr-defined]
    ax.set_box_aspect((1, 1, 1))  # type: ignore[arg-type]

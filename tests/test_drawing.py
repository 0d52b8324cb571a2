import numpy as np
import pytest
from conftest import SCENARIOS, robot
from matplotlib.figure import Figure

from vtm_pin import SimulationError, load_scenario, run_scenario
from vtm_pin.outputs.drawing import (
    compute_skeleton,
    draw_robot,
    plot_poses,
    plot_snapshots,
)

#: Forward kinematics against closed-form geometry: round-off of a few products of sines [m].
FK_TOL = 1e-12


def pendulum_points(q):
    """Closed-form joint origins and tip of the 3R pendulum (unit links, rotation about y)."""
    phi = np.cumsum(q)
    x = -np.concatenate([[0.0], np.cumsum(np.sin(phi))])
    z = -np.concatenate([[0.0], np.cumsum(np.cos(phi))])
    return np.column_stack([x, np.zeros(4), z])


@pytest.mark.parametrize("q", [np.zeros(3), np.array([0.3, -1.1, 2.0]), np.full(3, np.pi / 6)])
def test_pendulum_skeleton_matches_closed_form_geometry(q):
    skeleton = compute_skeleton(robot("planar_3r"), q)
    points = pendulum_points(q)
    np.testing.assert_allclose(skeleton.joints, points[:3], atol=FK_TOL)
    np.testing.assert_allclose(skeleton.tool, points[3], atol=FK_TOL)
    # joint1 -> joint2 -> joint3 -> tip: three unit links, each drawn once
    assert skeleton.segments.shape == (3, 2, 3)
    np.testing.assert_allclose(np.linalg.norm(np.diff(skeleton.segments, axis=1), axis=2), 1.0)
    np.testing.assert_allclose(skeleton.segments[-1, 1], points[3], atol=FK_TOL)


def test_branches_end_at_their_farthest_frame():
    fivebar = robot("planar_fivebar")
    skeleton = compute_skeleton(fivebar, np.zeros(fivebar.nv))
    # two arms of two links each; both roots hang from the world (one at the origin)
    assert skeleton.segments.shape == (4, 2, 3)
    assert skeleton.ground.shape == (2, 2, 3)
    ends = {tuple(np.round(s[1], 9)) for s in skeleton.segments}
    assert tuple(np.round(skeleton.tool, 9)) in ends


def test_planar_robot_is_drawn_in_its_plane_and_an_arm_in_3d():
    pendulum = draw_robot(robot("planar_3r"), np.zeros(3))
    assert pendulum.axes[0].name != "3d" and pendulum.axes[0].get_xlabel() == "x [m]"
    assert pendulum.axes[0].get_ylabel() == "z [m]"
    # rx160l at q = 0 lies in the x-z plane, but the robot is not planar: 3D
    arm = draw_robot(robot("rx160l"), np.zeros(6))
    assert arm.axes[0].name == "3d"


def test_poses_are_overlaid_with_rising_opacity():
    q = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [1.0, 0.0, 0.0]])
    fig = draw_robot(robot("planar_3r"), q, color="C3")
    ax = fig.axes[0]
    link_alphas = [line.get_alpha() for line in ax.lines if line.get_linewidth() == 3]
    # 3 links per pose, then an empty legend entry
    assert link_alphas[:9] == pytest.approx([0.25] * 3 + [0.625] * 3 + [1.0] * 3)
    tips = [line.get_xydata()[0] for line in ax.lines if line.get_marker() == "x"]
    expected = [pendulum_points(qi)[3][[0, 2]] for qi in q]
    np.testing.assert_allclose(tips, expected, atol=FK_TOL)


def test_drawing_into_given_axes_and_bad_views():
    fig = Figure()
    ax = fig.add_subplot()
    assert draw_robot(robot("planar_3r"), np.zeros(3), ax=ax) is fig
    with pytest.raises(ValueError, match="rx160l is not planar: draw it into 3D axes"):
        draw_robot(robot("rx160l"), np.zeros(6), ax=ax)
    with pytest.raises(ValueError, match="view 'top' is not one of auto, 3d, xy, xz, yz"):
        draw_robot(robot("planar_3r"), np.zeros(3), view="top")


def test_poses_figure_shows_both_rules_and_their_final_tips():
    scenario = load_scenario(SCENARIOS / "pendulum3r.yaml")
    results = {rule: run_scenario(scenario, rule) for rule in ("kkt", "naive")}
    fig = plot_poses(scenario.robot, results)
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels[0] == "initial" and labels[1].startswith("kkt") and labels[2].startswith("naive")
    tips = {
        tuple(np.round(line.get_xydata()[0], 12)) for line in ax.lines if line.get_marker() == "x"
    }
    for result in results.values():
        final = compute_skeleton(scenario.robot, result.q[-1]).tool[[0, 2]]
        assert tuple(np.round(final, 12)) in tips


def test_q_at_interpolates_samples_and_refuses_times_outside():
    result = run_scenario(load_scenario(SCENARIOS / "pendulum3r.yaml"))
    np.testing.assert_array_equal(result.q_at([0.0, 2.0]), result.q[[0, -1]])
    mid = 0.5 * (result.t[10] + result.t[11])
    np.testing.assert_allclose(result.q_at(mid)[0], 0.5 * (result.q[10] + result.q[11]))
    with pytest.raises(SimulationError, match=r"t = 2.5 s is outside the simulated \[0.0, 2.0\] s"):
        result.q_at([1.0, 2.5])


def test_snapshots_put_each_rule_in_its_own_panel_and_render(tmp_path):
    scenario = load_scenario(SCENARIOS / "pendulum3r.yaml")
    results = {rule: run_scenario(scenario, rule) for rule in ("kkt", "naive")}
    fig = plot_snapshots(scenario.robot, results, [0.0, 0.8, 1.3, 2.0])
    assert [ax.get_title() for ax in fig.axes] == [
        "kkt: t = 0, 0.8, 1.3, 2 s",
        "naive: t = 0, 0.8, 1.3, 2 s",
    ]
    labels = [t.get_text() for t in fig.axes[1].texts]
    assert labels == [" t = 0 s", " t = 0.8 s", " t = 1.3 s", " t = 2 s"]
    fig.savefig(tmp_path / "snapshots.png")  # layout and equal aspect must be drawable
    arm = load_scenario(SCENARIOS / "rx160l_paper_locks.yaml")
    fig = plot_snapshots(arm.robot, {"kkt": run_scenario(arm)}, [0.0, 0.3])
    assert fig.axes[0].name == "3d"
    fig.savefig(tmp_path / "arm.png")

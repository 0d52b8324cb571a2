"""Points on every link of the arm and S_arm, their largest displacement.

The module under test is vtm_pin.physics.arm_points.

The planar 3R pendulum has no collision geometry: its points lie on the segments between joint
origins (1 m links along -z at q = 0, all axes along y), so rigid rotations give chords in
closed form: a point at distance r from the axis turned by theta moves 2 r sin(theta / 2).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yaml
from conftest import KERNEL_PATHS, SCENARIOS, robot

from vtm_pin import load_scenario, run_scenario
from vtm_pin.cli import main
from vtm_pin.outputs.figures import stop_figures
from vtm_pin.outputs.stopping import compute_stopping_report
from vtm_pin.physics import body_kernel
from vtm_pin.physics.arm_points import (
    GEOMETRY,
    SEGMENTS,
    max_displacement,
    max_displacements,
    point_positions,
    sample_arm_points,
)
from vtm_pin.physics.kinematics import NUMPY_FROM, compute_tool_positions, joint_placements
from vtm_pin.physics.payload import Payload, attach_payload
from vtm_pin.physics.robot import load_robot

#: Round-off of a chord computed through Pinocchio's placements [m].
EXACT = 1e-12
PER_LINK = 50


def chord(radius: float, angle: float) -> float:
    """Straight-line distance a point at ``radius`` [m] from an axis moves when turned by
    ``angle`` [rad]."""
    return 2.0 * radius * math.sin(angle / 2.0)


def test_planar_3r_has_no_collision_geometry_and_samples_its_segments():
    r = robot("planar_3r")
    points = sample_arm_points(r, per_link=PER_LINK)
    assert points.source == SEGMENTS and "no <collision> elements" in points.note
    assert points.links == ("link1", "link2", "link3", "tool frame 'tip'")
    for k in range(3):
        mine = points.points[points.link == k]
        assert len(mine) == PER_LINK and points.spacing == 0.0
        # from the joint's origin to the next one (the tip for link3), 1 m straight down
        np.testing.assert_allclose(mine[[0, -1]], [[0, 0, 0], [0, 0, -1]], atol=EXACT)
    assert points.points.flags.writeable is False
    assert sample_arm_points(r, per_link=PER_LINK) is sample_arm_points(r, per_link=PER_LINK)


@pytest.mark.parametrize("theta", [0.3, 1.0, 2.5])
def test_turning_one_joint_moves_each_link_by_its_chord(theta):
    """Joint 2 turns by theta: link2's far end (1 m out) moves 2 sin(theta/2), link3's 4 sin."""
    r = robot("planar_3r")
    points = sample_arm_points(r, per_link=PER_LINK)
    q0, q1 = np.zeros(3), np.array([0.0, theta, 0.0])
    moved = np.linalg.norm(point_positions(r, points, q1) - point_positions(r, points, q0), axis=1)
    link2, link3 = points.link == 1, points.link == 2
    assert np.max(moved[link2]) == pytest.approx(chord(1.0, theta), abs=EXACT)
    assert np.max(moved[link3]) == pytest.approx(chord(2.0, theta), abs=EXACT)
    assert np.max(moved[points.link == 0]) <= EXACT  # link1 does not move
    result = max_displacement(r, points, np.linspace(q0, q1, 51))
    assert result.distance == pytest.approx(chord(2.0, theta), abs=EXACT)
    assert result.link in ("link3", "tool frame 'tip'") and result.sample == 50
    assert result.swept is not None and result.swept.shape == (51, len(points.points), 3)


def test_the_largest_displacement_may_be_reached_before_the_end():
    """Joint 1 turns 3 pi / 2: the tip (3 m out) is farthest, a diameter 6 m, at pi."""
    r = robot("planar_3r")
    points = sample_arm_points(r, per_link=PER_LINK)
    q = np.zeros((301, 3))
    q[:, 0] = np.linspace(0.0, 1.5 * math.pi, 301)
    result = max_displacement(r, points, q, swept=False)
    assert result.distance == pytest.approx(6.0, abs=EXACT) and result.sample == 200
    assert result.swept is None
    start, end = point_positions(r, points, q[0]), point_positions(r, points, q[-1])
    moved = np.linalg.norm(end - start, axis=1)
    assert np.max(moved) == pytest.approx(chord(3.0, 1.5 * math.pi), abs=EXACT)  # < 6 m


#: Two joints about z; link 'arm' carries a box 0.2 x 0.4 x 0.6 m centred 1 m out, a cylinder
#: and a sphere; link 'hand' carries none; the tool frame is 1.2 m out.
PRIMITIVES = """<?xml version="1.0"?>
<robot name="primitives">
  <link name="base"/>
  <joint name="j1" type="revolute">
    <parent link="base"/><child link="arm"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="100" velocity="2"/>
  </joint>
  <link name="arm">
    <inertial><origin xyz="0.5 0 0"/><mass value="2"/>
      <inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial>
    <collision><origin xyz="1 0 0"/><geometry>BOX</geometry></collision>
    <collision><origin xyz="0.5 0 0" rpy="0 1.5707963267948966 0"/>
      <geometry><cylinder radius="0.05" length="1.0"/></geometry></collision>
    <collision><origin xyz="0 0 0.3"/><geometry><sphere radius="0.1"/></geometry></collision>
  </link>
  <joint name="j2" type="revolute">
    <parent link="arm"/><child link="hand"/><origin xyz="1.1 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="100" velocity="2"/>
  </joint>
  <link name="hand">
    <inertial><origin xyz="0.05 0 0"/><mass value="0.5"/>
      <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
  </link>
  <joint name="tool_joint" type="fixed">
    <parent link="hand"/><child link="tool"/><origin xyz="0.1 0 0"/>
  </joint>
  <link name="tool"/>
</robot>
"""


def primitives(tmp_path: Path, box: str = '<box size="0.2 0.4 0.6"/>'):
    path = tmp_path / "primitives.urdf"
    path.write_text(PRIMITIVES.replace("BOX", box))
    return load_robot(str(path))


def test_primitives_give_their_hull_vertices(tmp_path):
    r = primitives(tmp_path)
    points = sample_arm_points(r, per_link=100)
    assert points.source == GEOMETRY
    assert points.links == ("arm", "hand", "tool frame 'tool'")
    assert "hand" in points.note  # no collision elements there: its segment is sampled
    arm = points.points[points.link == 0]
    assert len(arm) == 100  # the hull has more vertices: farthest-point sampling keeps 100
    corners = [[1 + x, y, z] for x in (-0.1, 0.1) for y in (-0.2, 0.2) for z in (-0.3, 0.3)]
    for corner in corners:  # every box corner is a hull vertex far out, and is kept
        assert np.min(np.linalg.norm(arm - corner, axis=1)) <= EXACT
    # nothing lies outside the shapes' bounding box (cylinder from x = 0, sphere up to 0.4)
    assert np.all(arm.min(axis=0) >= [-0.1 - EXACT, -0.2 - EXACT, -0.3 - EXACT])
    assert np.all(arm.max(axis=0) <= [1.1 + EXACT, 0.2 + EXACT, 0.4 + EXACT])
    assert 0.0 < points.spacing < 0.05
    # Turning joint 1 by theta: the box corner farthest from the axis, sqrt(1.1^2 + 0.2^2)
    # out, moves the most of link 'arm'; the tool frame (1.2 m out) more.
    theta = 0.7
    q = np.linspace([0.0, 0.0], [theta, 0.0], 21)
    moved = max_displacement(r, points, q)
    assert moved.distance == pytest.approx(chord(1.2, theta), abs=EXACT)
    swept = moved.swept
    assert swept is not None
    arm_moved = np.linalg.norm(swept[-1] - swept[0], axis=1)[points.link == 0]
    assert np.max(arm_moved) == pytest.approx(chord(math.hypot(1.1, 0.2), theta), abs=EXACT)


def test_a_missing_mesh_falls_back_to_segments_and_says_why(tmp_path):
    r = primitives(tmp_path, box='<mesh filename="missing.stl"/>')
    points = sample_arm_points(r)
    assert points.source == SEGMENTS
    assert "could not be loaded" in points.note and "missing.stl" in points.note
    assert points.links == ("arm", "hand", "tool frame 'tool'")


def test_ur10_samples_its_collision_meshes():
    """The arm's surface travels farther than the tool frame.

    S_arm >= S_s holds by construction (the tool frame's origin is one of the points). Turning
    the elbow 0.6 rad, the wrist housings (outside the flange's axis) travel a measured 1.12 x
    the tool frame's distance: the test asks for 1.05 x. Turning wrist 3 alone leaves the tool
    frame (on its axis) in place while the housing's rim moves a measured 27 mm (asked: 10 mm).
    """
    r = robot("ur10")
    points = sample_arm_points(r, per_link=100)
    assert points.source == GEOMETRY and points.note == ""
    moving = ("shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link")
    assert set(moving) <= set(points.links) and "base_link" not in points.links
    counts = np.bincount(points.link)
    assert np.all(counts[:-1] <= 100) and counts[-1] == 1  # the last link is the tool point
    assert points.spacing < 0.03  # [m]: farthest-point sampling of the hulls' vertices
    q0 = np.array([0.0, -1.2, 1.4, -1.2, -1.57, 0.0])
    for turn, factor, floor in ((2, 1.05, 0.0), (5, 0.0, 0.01)):
        q1 = q0.copy()
        q1[turn] += 0.6
        q = np.linspace(q0, q1, 61)
        tool = compute_tool_positions(r, q)
        s_s = float(np.max(np.linalg.norm(tool - tool[0], axis=1)))
        result = max_displacement(r, points, q, swept=False)
        assert math.isfinite(result.distance) and result.distance >= s_s - EXACT
        assert result.distance >= max(factor * s_s, floor), (turn, result, s_s)
        assert not result.link.startswith("tool frame")
    # a payload copy has the same joints: it shares the sample
    heavy = attach_payload(r, Payload(mass=5.0, com=(0.0, 0.0, 0.05)))
    assert sample_arm_points(heavy, per_link=100) is points


def test_run_reports_s_arm_beside_s_s(tmp_path, capsys):
    """Category-0 stop of the pendulum: S_arm in summary.json, >= S_s, with its upper bound."""
    raw = {
        "robot": "planar_3r",
        "initial": {"q": [1.0, 0.5, -0.3], "v": [1.5, -1.0, 0.5]},
        "duration": 1.0,
        "integrator": {"method": "dop853"},
        "brakes": {
            j: {"delay": 0.02, "sliding_torque": 9000.0, "static_torque": 12000.0}
            for j in ("joint1", "joint2", "joint3")
        },
        "stop": {"t": 0.0, "category": 0},
        "bounds": {"brake_wear": 0.2},
    }
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(raw))
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--no-plots"]) == 0
    printed = capsys.readouterr().out
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    figures = summary["figures"]
    values, upper = figures["values"], figures["upper"]
    assert values["arm_max_displacement"] >= values["tcp_max_displacement"] > 0.0
    assert upper["arm_max_displacement_upper"] >= upper["tcp_max_displacement_upper"]
    assert upper["arm_max_displacement_upper"] >= values["arm_max_displacement"]
    assert "any sampled point of the arm" in figures["definitions"]["arm_max_displacement"]
    assert figures["units"]["arm_max_displacement"] == "m"
    assert "S_arm" in printed


def pinocchio_displacement(robot_, points, qs):
    """S_arm the plain way: Pinocchio's joint placements sample by sample, every point's
    position, its distance from the first sample's: (largest, point, sample, positions)."""
    data = robot_.model.createData()
    swept = []
    for q in qs:
        pin.forwardKinematics(robot_.model, data, q)
        rotations = np.array([m.rotation for m in data.oMi])[points.joints]
        origins = np.array([m.translation for m in data.oMi])[points.joints]
        swept.append(np.einsum("kab,kb->ka", rotations, points.points) + origins)
    swept = np.array(swept)
    distance = np.linalg.norm(swept - swept[0], axis=2)
    sample, index = np.unravel_index(int(np.argmax(distance)), distance.shape)
    return float(distance[sample, index]), int(index), int(sample), swept


@pytest.mark.parametrize("name", ["ur10_annex_b", "ur10_estop_cat0"])
def test_s_arm_is_pinocchios_point_by_point_on_the_shipped_ur10_stops(name):
    """The vectorised S_arm against Pinocchio sample by sample (EXACT: round-off), on the
    whole stop (the NumPy path) and on its first 10 samples (fewer than NUMPY_FROM)."""
    scenario = load_scenario(SCENARIOS / f"{name}.yaml")
    result = run_scenario(scenario)
    report = compute_stopping_report(scenario.robot, result, scenario.brakes, scenario.tool_frame)
    i0 = int(np.argmax(result.t >= report.signal_time))
    points = sample_arm_points(scenario.robot)
    assert points.source == GEOMETRY and len(result.q) - i0 >= NUMPY_FROM
    whole = pinocchio_displacement(scenario.robot, points, result.q[i0:])[0]
    for qs in (result.q[i0:], result.q[i0 : i0 + 10]):
        distance, index, sample, swept = pinocchio_displacement(scenario.robot, points, qs)
        arm = max_displacement(scenario.robot, points, qs)
        assert arm.distance == pytest.approx(distance, rel=0, abs=EXACT)
        assert (arm.index, arm.sample) == (index, sample)
        assert arm.swept is not None
        np.testing.assert_allclose(arm.swept, swept, rtol=0, atol=EXACT)
    figures = stop_figures(scenario, result, report)
    assert figures.metrics["arm_max_displacement"] == pytest.approx(whole, rel=0, abs=EXACT)
    assert figures.metrics["arm_max_displacement"] >= figures.metrics["tcp_max_displacement"]


def test_on_a_tie_the_first_sample_and_then_the_first_point_is_named():
    """Joint 1 turns to pi, back to 0 and to pi again: the largest displacement, 6 m, is
    reached at both visits of pi (the same configuration: the same figures to the bit) by
    link3's far end and the tip (the same place): the first sample and point are named."""
    r = robot("planar_3r")
    points = sample_arm_points(r, per_link=PER_LINK)
    there, back = np.linspace(0.0, math.pi, 40), np.linspace(math.pi, 0.0, 40)
    q = np.zeros((118, 3))
    q[:, 0] = np.concatenate([there, back[1:], there[1:]])
    assert q[39, 0] == q[117, 0] == math.pi and len(q) >= NUMPY_FROM
    result = max_displacement(r, points, q, swept=False)
    assert result.distance == pytest.approx(6.0, abs=EXACT)
    assert result.sample == 39 and result.link == "link3"
    assert result.index == int(np.flatnonzero(points.link == 2)[-1])  # its far end


def brute_force_displacements(r, points, q):
    """|p_i(q_t) - p_i(q_0)| of every point at every sample [m], shape (T, k), by Pinocchio."""
    model, data = r.model, r.model.createData()
    placed = []
    for qt in q:
        pin.forwardKinematics(model, data, qt)
        world = np.empty_like(points.points)
        for j in np.unique(points.joints):
            mine = points.joints == j
            world[mine] = points.points[mine] @ data.oMi[int(j)].rotation.T
            world[mine] += data.oMi[int(j)].translation
        placed.append(world)
    placed = np.array(placed)
    return np.linalg.norm(placed - placed[0], axis=2)


@pytest.mark.parametrize("name", ["ur10", "panda"])
def test_the_bounded_search_finds_the_largest_displacement_of_all_points_and_samples(name):
    """max_displacement forms a joint's points only where a bound says they may hold the
    largest displacement: on random walks of every size of step (some at rest after half the
    run, one not moving at all) it finds what forming every point at every sample finds.
    Tolerance: Pinocchio's placements against vtm_pin's NumPy ones, 1e-12 relative (1e-14 m
    for a displacement near 0)."""
    r = robot(name)
    points = sample_arm_points(r, per_link=PER_LINK)
    rng = np.random.default_rng(27)
    for trial in range(9):
        count = int(rng.integers(NUMPY_FROM, 160))
        scale = [1e-6, 1e-3, 0.05][trial % 3]
        q = rng.uniform(-2.0, 2.0, r.nv) + np.cumsum(rng.normal(0, scale, (count, r.nv)), axis=0)
        if trial % 4 == 1:
            q[count // 2 :] = q[count // 2]  # at rest: the largest is tied to the end
        if trial == 8:
            q[:] = q[0]
        moved = brute_force_displacements(r, points, q)
        result = max_displacement(r, points, q, swept=False)
        assert result.distance == pytest.approx(moved.max(), rel=1e-12, abs=1e-14), trial
        # the point and sample it names move that far
        named = moved[result.sample, result.index]
        assert named == pytest.approx(result.distance, rel=1e-12, abs=1e-14), trial
        if trial % 4 == 1:
            assert result.sample <= count // 2  # the first sample of the tie
        if trial == 8:
            assert (result.distance, result.index, result.sample) == (0.0, 0, 0)


@KERNEL_PATHS
@pytest.mark.parametrize("name", ["ur10", "panda"])
def test_many_trajectories_at_once_find_what_each_finds_alone(name, compiled, monkeypatch):
    """max_displacements (a study's reports, together) against max_displacement one by one
    and against every point at every sample, on the random walks above in one call, with a
    trajectory of one sample and the tie of the planar arm's test: the same distance to
    round-off (1e-12 relative, 1e-14 m), the same point and sample (its tie rule included).
    On either path (the compiled kernel's sums run in another order: round-off)."""
    monkeypatch.setattr(body_kernel, "AVAILABLE", compiled)
    r = robot(name)
    points = sample_arm_points(r, per_link=PER_LINK)
    rng = np.random.default_rng(28)
    walks = []
    for trial in range(12):
        count = 1 if trial == 5 else int(rng.integers(2, 120))
        scale = [1e-6, 1e-3, 0.05][trial % 3]
        q = rng.uniform(-2.0, 2.0, r.nv) + np.cumsum(rng.normal(0, scale, (count, r.nv)), axis=0)
        if trial % 4 == 1:
            q[count // 2 :] = q[count // 2]
        if trial == 8:
            q[:] = q[0]
        walks.append(q)
    placements = [joint_placements(r, q) for q in walks]
    together = max_displacements(points, placements)
    assert len(together) == len(walks)
    for trial, (q, arm) in enumerate(zip(walks, together, strict=True)):
        alone = max_displacement(r, points, q, swept=False, placements=placements[trial])
        moved = brute_force_displacements(r, points, q)
        assert arm.distance == pytest.approx(alone.distance, rel=1e-12, abs=1e-14), trial
        assert arm.distance == pytest.approx(moved.max(), rel=1e-12, abs=1e-14), trial
        assert (arm.index, arm.sample, arm.link) == (alone.index, alone.sample, alone.link)


@KERNEL_PATHS
def test_many_at_once_name_the_first_sample_and_point_of_a_tie(compiled, monkeypatch):
    monkeypatch.setattr(body_kernel, "AVAILABLE", compiled)
    r = robot("planar_3r")
    points = sample_arm_points(r, per_link=PER_LINK)
    there, back = np.linspace(0.0, math.pi, 40), np.linspace(math.pi, 0.0, 40)
    q = np.zeros((118, 3))
    q[:, 0] = np.concatenate([there, back[1:], there[1:]])
    still = np.zeros((5, 3))
    tie, rest = max_displacements(points, [joint_placements(r, q), joint_placements(r, still)])
    assert tie.distance == pytest.approx(6.0, abs=EXACT)
    assert tie.sample == 39 and tie.index == int(np.flatnonzero(points.link == 2)[-1])
    assert (rest.distance, rest.index, rest.sample) == (0.0, 0, 0)

import json

import numpy as np
import planar_reference as ref
import pytest
from conftest import ROOT, robot

from vtm_pin import (
    Drive,
    JointNotFound,
    RobotDataError,
    RobotLoadError,
    RobotNotFound,
    UnsupportedJoint,
    compute_bias,
    compute_M,
    load_robot,
)
from vtm_pin.cli import main
from vtm_pin.physics.robot import list_local_robots

# Pinocchio and the closed-form Kane model sum the same terms in a different order:
# they agree to round-off, ~1e-13 of entries of size ~1e3.
CLOSED_FORM_RTOL = 1e-11


def test_planar_3r_matches_closed_form_dynamics():
    r = robot("planar_3r")
    data = r.model.createData()
    rng = np.random.default_rng(1)
    for _ in range(20):
        q, v = rng.uniform(-np.pi, np.pi, 3), rng.uniform(-5, 5, 3)
        M = compute_M(r.model, data, q)
        np.testing.assert_allclose(M, ref.mass_matrix(q), rtol=CLOSED_FORM_RTOL, atol=1e-10)
        np.testing.assert_allclose(
            compute_bias(r.model, data, q, v), ref.bias(q, v), rtol=CLOSED_FORM_RTOL, atol=1e-10
        )


def test_planar_3r_has_paper_parameters():
    r = robot("planar_3r")
    assert r.joints == ("joint1", "joint2", "joint3")
    assert r.model.nq == r.model.nv == 3
    np.testing.assert_array_equal(r.model.gravity.linear, [0.0, 0.0, -9.81])
    for jid in (1, 2, 3):
        inertia = r.model.inertias[jid]
        assert inertia.mass == 108.0
        np.testing.assert_allclose(inertia.lever, [0.0, 0.0, -0.5])


@pytest.mark.parametrize("name", list_local_robots())
def test_every_local_robot_loads(name):
    r = load_robot(name)
    assert r.nv == len(r.joints) > 0


def test_load_by_path_and_relative_path():
    path = ROOT / "robots" / "planar_3r.urdf"
    assert load_robot(path).joints == robot("planar_3r").joints
    assert load_robot("planar_3r.urdf", base_dir=ROOT / "robots").nv == 3


@pytest.mark.parametrize("name, nv", [("ur5", 6), ("panda", 9)])
def test_load_example_robot_data(name, nv):
    assert robot(name).nv == nv


def test_drive_sets_reflected_inertia():
    plain = load_robot("planar_3r")
    geared = load_robot("planar_3r", drives={"joint2": Drive(gear_ratio=100, rotor_inertia=2e-4)})
    q = np.array([0.3, -0.2, 0.1])
    dM = compute_M(geared.model, geared.model.createData(), q) - compute_M(
        plain.model, plain.model.createData(), q
    )
    expected = np.zeros((3, 3))
    expected[1, 1] = 100**2 * 2e-4
    np.testing.assert_allclose(dM, expected, atol=1e-12)
    assert geared.gear_ratio.tolist() == [1.0, 100.0, 1.0]


def test_unknown_robot_names_the_choices():
    with pytest.raises(RobotNotFound, match=r"Robot 'no_such_arm' not found.*planar_3r.*ur5"):
        load_robot("no_such_arm")


def test_missing_urdf_file():
    with pytest.raises(RobotLoadError, match=r"'missing\.urdf': no such file"):
        load_robot("missing.urdf")


def test_broken_urdf_gives_urdfdom_reason(tmp_path):
    bad = tmp_path / "bad.urdf"
    bad.write_text(
        '<robot name="b"><link name="a"/><link name="c"/><joint name="j" type="revolute">'
        '<parent link="a"/><child link="c"/></joint></robot>'
    )
    with pytest.raises(RobotLoadError, match=r"bad\.urdf'.*does not specify limits"):
        load_robot(bad)


def test_continuous_joint_is_rejected(tmp_path):
    urdf = tmp_path / "cont.urdf"
    urdf.write_text(
        '<robot name="c"><link name="a"/><link name="b"><inertial><mass value="1"/>'
        '<inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>'
        '<joint name="spin" type="continuous"><parent link="a"/><child link="b"/>'
        '<axis xyz="0 0 1"/></joint></robot>'
    )
    with pytest.raises(UnsupportedJoint, match=r"Joint 'spin'.*use 'revolute' instead"):
        load_robot(urdf)


def test_drive_on_unknown_joint():
    with pytest.raises(JointNotFound, match=r"Joint 'elbow' not in the model.*joint1, joint2"):
        load_robot("planar_3r", drives={"elbow": Drive()})


# --- physical validity of a URDF's inertias -------------------------------------------------

URDF = (ROOT / "robots" / "planar_3r.urdf").read_text()
MASS = '<mass value="108"/>'
INERTIA = 'ixx="9.36" ixy="0" ixz="0" iyy="9.36" iyz="0" izz="0.72"'


def write_urdf(tmp_path, text, name="bot"):
    path = tmp_path / f"{name}.urdf"
    path.write_text(text)
    return path


def last_link(mass, inertia):
    """planar_3r with the last link's mass and inertia replaced."""
    i, j = URDF.rfind(MASS), URDF.rfind(INERTIA)
    return URDF[:i] + mass + URDF[i + len(MASS) : j] + inertia + URDF[j + len(INERTIA) :]


@pytest.mark.parametrize(
    "text, message",
    [
        (
            URDF.replace(MASS, '<mass value="nan"/>', 1),
            r"link 'link1': Inertial: mass \[nan\] is not a float",
        ),
        (last_link('<mass value="-1"/>', INERTIA), r"link 'link3': mass -1 kg is outside"),
        (
            URDF.replace('ixy="0"', 'ixy="50"', 1),
            r"link 'link1': rotational inertia is not positive semi-definite",
        ),
        (
            URDF.replace('izz="0.72"', 'izz="30"', 1),
            r"link 'link1': principal moments 9.36, 9.36, 30 kg m\^2 break the triangle inequality",
        ),
        (
            last_link('<mass value="0"/>', 'ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"'),
            r"joint 'joint3' moves no mass or inertia: link 'link3'",
        ),
        (
            URDF.replace('<axis xyz="0 1 0"/>', '<axis xyz="0 0 0"/>', 1),
            r"joint 'joint1' has no axis",
        ),
        ('<robot name="r"><link name="base"/></robot>', r"has no moving joint"),
    ],
    ids=[
        "nan mass",
        "negative mass",
        "not PD",
        "triangle",
        "massless leaf",
        "zero axis",
        "no joint",
    ],
)
def test_unphysical_robot_is_refused_naming_the_link(tmp_path, text, message):
    with pytest.raises(RobotLoadError, match=r"bot\.urdf': " + message) as info:
        load_robot(write_urdf(tmp_path, text))
    assert "\n" not in str(info.value)


def test_triangle_inequality_allows_rounded_figures(tmp_path):
    # A thin plate has I_z = I_x + I_y exactly; rounded to 4 digits it may exceed by ~1e-4.
    plate = URDF.replace(INERTIA, 'ixx="1.001" ixy="0" ixz="0" iyy="1" iyz="0" izz="2.0015"', 1)
    assert load_robot(write_urdf(tmp_path, plate)).nv == 3


def test_massless_leaf_moves_when_its_joint_has_a_rotor(tmp_path):
    path = write_urdf(
        tmp_path, last_link('<mass value="0"/>', 'ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"')
    )
    assert load_robot(path, drives={"joint3": Drive(gear_ratio=10, rotor_inertia=1e-3)}).nv == 3


# --- robot data files beside a URDF ---------------------------------------------------------


@pytest.mark.parametrize(
    "content, message",
    [
        ("drives:\n  joint1: {gear_ratio: -5}\n", r"'drives.joint1.gear_ratio': -5 must be > 0"),
        ("drives:\n  joint2: {rotor_inertia: -1}\n", r"'drives.joint2.rotor_inertia': -1 must be"),
        ("drives:\n  elbow: {gear_ratio: 2}\n", r"'drives.elbow': unknown joint; the joints are"),
        ("drive: {}\n", r"'drive': unknown key; allowed keys here: assumptions, brakes, drives"),
        ("drives: [\n  joint1: {gear_ratio: 2}\n", r"not valid YAML at line 3: expected"),
    ],
)
def test_robot_data_file_follows_the_scenario_rules_in_one_line(tmp_path, content, message):
    (tmp_path / "bot.yaml").write_text(content)
    with pytest.raises(RobotDataError, match=r"bot\.yaml: " + message) as info:
        load_robot(write_urdf(tmp_path, URDF))
    assert "\n" not in str(info.value)


def test_robot_data_file_gives_drives_and_a_scenario_beside_the_urdf_is_not_one(tmp_path):
    path = write_urdf(tmp_path, URDF)
    (tmp_path / "bot.yaml").write_text("drives:\n  joint2: {gear_ratio: 50, rotor_inertia: 1e-4}\n")
    assert load_robot(path).gear_ratio.tolist() == [1.0, 50.0, 1.0]
    (tmp_path / "bot.yaml").write_text("robot: bot.urdf\ninitial: {q: [0, 0, 0]}\nduration: 1\n")
    assert load_robot(path).gear_ratio.tolist() == [1.0, 1.0, 1.0]


def test_robot_cache_loads_once_and_keeps_the_most_recent():
    from vtm_pin.physics.robot import Drive, RobotCache

    cache = RobotCache(size=2)
    first = cache("planar_3r")
    assert cache("planar_3r") is first
    geared = cache("planar_3r", drives={"joint1": Drive(gear_ratio=2.0)})
    assert geared is not first and geared.gear_ratio[0] == 2.0
    cache("ur5")  # a third robot: the least recently used one, plain planar_3r, goes
    assert cache("planar_3r", drives={"joint1": Drive(gear_ratio=2.0)}) is geared
    assert cache("planar_3r") is not first


ONE_JOINT_URDF = """<?xml version="1.0"?>
<robot name="one">
  <link name="base"/>
  <link name="arm"><inertial><origin xyz="0 0 -0.5"/><mass value="1"/>
    <inertia ixx="0.1" iyy="0.1" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="arm"/><axis xyz="0 1 0"/>
    <limit lower="-3" upper="3" effort="10" velocity="2"/></joint>
</robot>
"""


def test_a_one_joint_robot_loads_and_runs(tmp_path, capsys):
    """Pinocchio gives a one-joint model's matrices as vectors; the checks shape them back."""
    (tmp_path / "one.urdf").write_text(ONE_JOINT_URDF)
    (tmp_path / "s.yaml").write_text(
        "robot: one.urdf\ninitial: {q: [1.0]}\nduration: 0.5\nevents:\n  - {t: 0.2, lock: [j1]}\n"
    )
    assert (
        main(
            ["run", str(tmp_path / "s.yaml"), "--no-plots", "--json", "--out", str(tmp_path / "o")]
        )
        == 0
    )
    summary = json.loads(capsys.readouterr().out)
    assert summary["robot"] == "one.urdf" and len(summary["events"]) == 1


def test_a_worker_keeps_its_drivers_example_models_and_builds_none(monkeypatch, tmp_path):
    """A study's pool workers are handed their driver's example-robot-data models, pickled:
    each loads the robot from them (the same model, its dynamics to the bit) and does not
    build it again from the URDF (~0.45 s for the UR10, meshes included)."""
    import pickle

    import example_robot_data
    import pinocchio as pin

    from vtm_pin.physics import robot as robot_module

    monkeypatch.setenv("VTM_PIN_CACHE", str(tmp_path))  # none kept on disk either
    fresh = robot_module.load_robot("ur10")
    handed = pickle.loads(pickle.dumps(robot_module.example_models()))
    assert "ur10" in handed
    monkeypatch.setattr(robot_module, "_EXAMPLE_MODELS", robot_module.ModelCache(16))

    def refuse(*args, **kwargs):
        raise AssertionError("built again from the URDF")

    monkeypatch.setattr(example_robot_data, "load", refuse)
    robot_module.keep_example_models(handed)
    kept = robot_module.load_robot("ur10")
    assert kept.model == fresh.model and kept.source == fresh.source
    q, v, a = np.full(6, 0.3), np.full(6, -0.7), np.full(6, 1.1)
    assert np.array_equal(
        pin.rnea(kept.model, kept.model.createData(), q, v, a),
        pin.rnea(fresh.model, fresh.model.createData(), q, v, a),
    )


def test_example_models_are_kept_on_disk_exactly_and_rebuilt_when_stale(monkeypatch, tmp_path):
    """An example-robot-data model is built once (its meshes too, ~0.45 s for the UR10) and
    then read from the model store: equal to the one built. A damaged file, or one whose
    URDF has changed since, is built again and rewritten; a folder that cannot be written
    only means that nothing is kept."""
    import example_robot_data

    from vtm_pin.files import model_store
    from vtm_pin.physics import robot as robot_module

    monkeypatch.setenv("VTM_PIN_CACHE", str(tmp_path))
    built = []
    load = example_robot_data.load

    def counted(name, *args, **kwargs):
        built.append(name)
        return load(name, *args, **kwargs)

    monkeypatch.setattr(example_robot_data, "load", counted)

    def fresh_load():
        monkeypatch.setattr(robot_module, "_EXAMPLE_MODELS", robot_module.ModelCache(16))
        return robot_module.load_robot("ur5")

    first = fresh_load()
    (kept,) = (tmp_path / "models").glob("ur5-*.json")
    again = fresh_load()
    assert built == ["ur5"] and again.model == first.model and again.source == first.source
    kept.write_text(kept.read_text()[:-200])  # damaged
    assert fresh_load().model == first.model and built == ["ur5"] * 2
    entry = json.loads(kept.read_text())  # rewritten whole
    entry["stat"][0] += 1  # the URDF changed since
    kept.write_text(json.dumps(entry))
    assert fresh_load().model == first.model and built == ["ur5"] * 3
    assert model_store.read("ur5", {"pinocchio": "0"}) is None  # other versions: not this file
    blocked = tmp_path / "a file"  # its models folder cannot be made, even by root
    blocked.write_text("")
    monkeypatch.setenv("VTM_PIN_CACHE", str(blocked))
    assert fresh_load().model == first.model and built == ["ur5"] * 4

import copy

import numpy as np
import pytest
import yaml
from conftest import ROOT, SCENARIOS

from vtm_pin import ScenarioError, build_scenario, load_scenario, run_scenario

BASE = {
    "robot": "planar_3r",
    "initial": {"q": [0.5, 0.5, 0.5], "v": [0.0, 0.0, 0.0]},
    "duration": 2.0,
    "integrator": {"method": "rk4", "dt": 1.0e-3},
    "transition": "kkt",
    "events": [{"t": 0.8, "lock": ["joint2"]}, {"t": 1.3, "lock": ["joint3"]}],
}


def changed(path, value):
    raw = copy.deepcopy(BASE)
    node = raw
    for key in path[:-1]:
        node = node[key]
    if value is KeyError:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return raw


BAD = [
    (
        changed(["colour"], "red"),
        r"'colour': unknown key; allowed keys here: assumptions, brakes, constraints, ",
    ),
    (changed(["duration"], "long"), r"'duration': 'long' is not of type number"),
    (changed(["duration"], -1.0), r"'duration': -1.0 must be > 0"),
    (changed(["integrator", "dt"], -1e-4), r"'integrator.dt': -0.0001 must be > 0"),
    (changed(["integrator", "dt"], 5.0), r"'integrator.dt': 5.0 must be a finite step in"),
    (
        changed(["integrator", "method"], "rk5"),
        r"'integrator.method'.*allowed values: dop853, euler, rk4",
    ),
    (changed(["integrator", "rtol"], 1e-6), r"'integrator.rtol': applies to dop853 only"),
    (
        changed(["integrator"], {"method": "dop853", "dt": 1e-3}),
        r"'integrator.dt': dop853 chooses its own steps",
    ),
    (changed(["integrator"], {"method": "dop853", "rtol": 0}), r"'integrator.rtol': 0 must be >"),
    (changed(["transition"], "magic"), r"allowed values: kkt, minimal, naive, projected"),
    (changed(["robot"], "no_such_arm"), r"'robot': Robot 'no_such_arm' not found"),
    (changed(["robot"], 7), r"'robot': 7 is not of type string"),
    (changed(["initial", "q"], [0.1, 0.2]), r"'initial.q': has 2 values but the robot has 3"),
    (changed(["initial", "q"], {"knee": 1.0}), r"'initial.q': unknown joint 'knee'; the joints"),
    (changed(["events"], [{"t": 2.5, "lock": ["joint2"]}]), r"'events\[0\].t': 2.5 s is outside"),
    (changed(["events"], [{"t": -0.1, "lock": ["joint2"]}]), r"'events\[0\].t': -0.1 s is outside"),
    (changed(["events"], [{"t": 1.0, "lock": ["knee"]}]), r"'events\[0\].lock': unknown joint"),
    (
        changed(["events"], [{"t": 1.0, "lock": ["joint2"]}, {"t": 0.5, "lock": ["joint2"]}]),
        r"'events\[0\].lock': joint 'joint2' locks again at t = 1.0 s but is already locked",
    ),
    (changed(["events"], [{"t": 1.0, "lock": []}]), r"'events\[0\].lock': must list at least one"),
    (changed(["events"], [{"t": 1.0}]), r"'events\[0\]': needs 'lock' or 'activate'"),
    (changed(["duration"], KeyError), r"'duration' is missing"),
    (changed(["drives"], {"knee": {"gear_ratio": 100}}), r"'drives.knee': unknown joint"),
    (
        changed(["drives"], {"joint1": {"gear_ratio": 0}}),
        r"'drives.joint1.gear_ratio': 0 must be >",
    ),
]


@pytest.mark.parametrize("raw, message", BAD, ids=[m for _, m in BAD])
def test_bad_scenario_gives_one_clear_line(tmp_path, raw, message):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(raw))
    with pytest.raises(ScenarioError, match=message) as info:
        load_scenario(path)
    text = str(info.value)
    assert text.startswith(str(path)) and "\n" not in text


def test_broken_urdf_in_scenario(tmp_path):
    (tmp_path / "broken.urdf").write_text("<robot name='x'><link name='a'/><joint/></robot>")
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(changed(["robot"], "broken.urdf")))
    with pytest.raises(ScenarioError, match=r"s\.yaml: 'robot': Could not load robot from"):
        load_scenario(path)


def test_yaml_syntax_error_and_missing_file(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text("robot: [planar_3r\nduration: 2\n")
    with pytest.raises(ScenarioError, match=r"s\.yaml: not valid YAML at line"):
        load_scenario(path)
    with pytest.raises(ScenarioError, match=r"nope\.yaml: cannot read the file"):
        load_scenario(tmp_path / "nope.yaml")
    path.write_text("- just\n- a list\n")
    with pytest.raises(ScenarioError, match="must be a mapping"):
        load_scenario(path)


def test_joint_mapping_and_defaults():
    raw = {"robot": "planar_3r", "initial": {"q": {"joint2": 0.3}}, "duration": 1.0}
    scenario = build_scenario(raw)
    assert scenario.q0.tolist() == [0.0, 0.3, 0.0]
    assert scenario.v0.tolist() == [0.0, 0.0, 0.0]
    assert scenario.integrator.dt == 1e-4
    assert scenario.transition == "kkt"
    assert scenario.events == ()


def test_relative_urdf_path_resolves_against_scenario(tmp_path):
    path = tmp_path / "s.yaml"
    urdf = ROOT / "robots" / "planar_3r.urdf"
    (tmp_path / "arm.urdf").write_text(urdf.read_text())
    path.write_text(yaml.safe_dump(changed(["robot"], "arm.urdf")))
    assert load_scenario(path).robot.source == str(tmp_path / "arm.urdf")


@pytest.mark.parametrize("path", sorted(SCENARIOS.glob("*.yaml")), ids=lambda p: p.name)
def test_every_shipped_scenario_runs(path):
    scenario = load_scenario(path)
    result = run_scenario(scenario)
    assert result.t[-1] == scenario.duration
    prescribed = {e.t for e in scenario.events}
    assert prescribed <= {e.t for e in result.events if e.kind in ("lock", "activate")}
    if scenario.stop is not None:
        assert np.all(result.v[-1] == 0.0)  # every shipped e-stop ends with the arm at rest

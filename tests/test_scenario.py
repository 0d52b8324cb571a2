import copy
import math

import numpy as np
import pytest
import yaml
from conftest import ROOT, SCENARIOS

from vtm_pin import ScenarioError, build_scenario, load_scenario, run_scenario
from vtm_pin.scene.scenario import SCHEMA

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
        r"'colour': unknown key; allowed keys here: annex_b, assumptions, bounds, brakes, "
        r"calibration, constraints, ",
    ),
    (changed(["duration"], "long"), r"'duration': 'long' is not a number"),
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
    (
        changed(["integrator"], {"method": "dop853", "rtol": 0}),
        r"'integrator.rtol': 0 must be >= 1e-13",
    ),
    (changed(["transition"], "magic"), r"allowed values: kkt, minimal, naive, projected"),
    (changed(["robot"], "no_such_arm"), r"'robot': Robot 'no_such_arm' not found"),
    (changed(["robot"], 7), r"'robot': 7 is not a string"),
    (changed(["initial", "q"], [0.1, 0.2]), r"'initial.q': has 2 values but the robot has 3"),
    (changed(["initial", "q"], {"knee": 1.0}), r"'initial.q': unknown joint 'knee'; the joints"),
    (changed(["events"], [{"t": 2.5, "lock": ["joint2"]}]), r"'events\[0\].t': 2.5 s is outside"),
    (changed(["events"], [{"t": -0.1, "lock": ["joint2"]}]), r"'events\[0\].t': -0.1 must be >= 0"),
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
    if scenario.stop is not None and scenario.stop.category == 2:
        # The drives hold the arm (no brake locks it): at rest to round-off, 1e-12 rad/s.
        assert np.all(np.abs(result.v[-1]) <= 1e-12)
    elif scenario.stop is not None:
        assert np.all(result.v[-1] == 0.0)  # every shipped e-stop ends with the arm at rest


def test_scenario_beside_a_urdf_of_the_same_stem_is_not_its_robot_data(tmp_path):
    (tmp_path / "arm.urdf").write_text((ROOT / "robots" / "planar_3r.urdf").read_text())
    path = tmp_path / "arm.yaml"
    raw = {**changed(["robot"], "arm.urdf"), "duration": 0.01, "events": []}
    path.write_text(yaml.safe_dump(raw))
    scenario = load_scenario(path)
    assert scenario.robot.source == str(tmp_path / "arm.urdf")
    assert run_scenario(scenario).t[-1] == 0.01


def test_fixed_step_run_longer_than_max_steps_is_refused_up_front(tmp_path):
    path = tmp_path / "long.yaml"
    path.write_text(yaml.safe_dump(changed(["integrator"], {"method": "rk4", "dt": 1e-300})))
    with pytest.raises(
        ScenarioError,
        match=r"'integrator.dt': rk4 with dt = 1e-300 s would take 2e\+300 steps for 2 s; the "
        r"limit is 1000000: set integrator.max_steps, or a larger dt",
    ):
        load_scenario(path)
    raw = changed(["integrator"], {"method": "euler", "dt": 1e-3, "max_steps": 1999})
    with pytest.raises(ScenarioError, match=r"would take 2000 steps .* the limit is 1999"):
        build_scenario(raw)
    assert build_scenario(changed(["integrator", "max_steps"], 2000)).integrator.max_steps == 2000


def test_dop853_stops_past_max_steps_naming_the_key():
    raw = changed(["integrator"], {"method": "dop853", "max_steps": 5})
    with pytest.raises(
        ScenarioError, match=r"'integrator.max_steps': dop853 took 5 steps from t = 0 s and"
    ):
        run_scenario(build_scenario(raw, source="s.yaml"))


def test_docking_away_from_its_target_is_refused_with_key_and_distance():
    raw = yaml.safe_load((SCENARIOS / "rx160l_dock_point.yaml").read_text())
    raw["duration"] = 0.02
    raw["events"] = [
        {
            "t": 0.01,
            "activate": [{"type": "dock", "frame_a": "tool0", "target": {"xyz": [1, 1, 1]}}],
        }
    ]
    with pytest.raises(
        ScenarioError,
        match=r"'events\[0\].activate\[0\].target': Constraint 'dock0' activates at t = 0.01 s "
        r"[0-9.]+ m and 0 rad away from where it holds; it must activate within 0.001 m",
    ):
        run_scenario(build_scenario(raw, source="s.yaml"))


@pytest.mark.parametrize(
    "path, value, message",
    [
        (["stabilisation"], {"alpha": 1e300}, r"'stabilisation.alpha': 1e\+300 must be <= 1000"),
        (["duration"], 1e308, r"'duration': 1e\+308 must be <= 3600"),
        (["initial", "v"], [1e308, 0, 0], r"'initial.v\[0\]': 1e\+308 must be <= 1000"),
        (["drives"], {"joint1": {"rotor_inertia": math.inf}}, r"rotor_inertia': inf is not a fin"),
        (["integrator"], {"method": "dop853", "atol": math.nan}, r"'integrator.atol': nan is not"),
        (["integrator"], {"method": "dop853", "atol": math.inf}, r"'integrator.atol': inf is not"),
        (["stop"], {"category": 1, "ramp_time": math.inf}, r"'stop.ramp_time': inf is not a fin"),
        (
            ["constraints"],
            [{"type": "dock", "frame_a": "tip", "target": {"xyz": [0, math.nan, 0]}}],
            r"'constraints\[0\].target.xyz\[1\]': nan is not a finite number",
        ),
        (["duration"], 10**400, r"'duration': <an integer of 400 digits> is not a finite number"),
    ],
)
def test_extreme_values_are_refused_when_read_with_their_key(tmp_path, path, value, message):
    path_file = tmp_path / "x.yaml"
    path_file.write_text(yaml.safe_dump(changed(path, value)))
    with pytest.raises(ScenarioError, match=message):
        load_scenario(path_file)


def test_brake_torque_of_1e308_is_refused():
    raw = yaml.safe_load((SCENARIOS / "rx160l_estop_cat0.yaml").read_text())
    raw["brakes"]["joint_1"] = {"sliding_torque": 1e308}
    with pytest.raises(ScenarioError, match=r"'brakes.joint_1.sliding_torque': 1e\+308 must be <="):
        build_scenario(raw)


def number_schemas(schema, path="SCHEMA"):
    if schema.get("type") == "number":
        yield path, schema
    for key, sub in schema.get("properties", {}).items():
        yield from number_schemas(sub, f"{path}.{key}")
    for key in ("items", "additionalProperties"):
        if isinstance(schema.get(key), dict):
            yield from number_schemas(schema[key], f"{path}.{key}")
    for i, sub in enumerate(schema.get("oneOf", [])):
        yield from number_schemas(sub, f"{path}.oneOf[{i}]")


def test_every_number_of_the_schema_has_finite_bounds():
    found = list(number_schemas(SCHEMA))
    assert len(found) > 20
    for path, schema in found:
        low = schema.get("minimum", schema.get("exclusiveMinimum"))
        assert low is not None and math.isfinite(low), path
        assert math.isfinite(schema.get("maximum", math.inf)), path


@pytest.mark.parametrize("method", ["rk4", "euler", "dop853"])
def test_events_closer_than_a_step_finish(method):
    """Two locks 1e-14 s apart: the interval between them is shorter than any step."""
    raw = changed(
        ["events"], [{"t": 0.05, "lock": ["joint2"]}, {"t": 0.05 + 1e-14, "lock": ["joint3"]}]
    )
    raw["duration"] = 0.1
    raw["integrator"] = {"method": method} if method == "dop853" else {"method": method, "dt": 1e-3}
    result = run_scenario(build_scenario(raw))
    assert result.t[-1] == 0.1 and [e.lock for e in result.events] == [("joint2",), ("joint3",)]

"""A rigid payload fixed to a robot frame (``vtm_pin.physics.payload``).

The dynamics of a robot carrying a payload are checked against an independent Pinocchio
model: the robot's URDF with the payload appended by hand as a link on a fixed joint, which
Pinocchio's URDF parser merges into the parent body itself. Properties (symmetric positive
definite mass matrix, total mass) hold over random payloads; bad payloads are refused with
the sub-key they break.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from conftest import robot
from hypothesis import given, settings
from hypothesis import strategies as st

from vtm_pin.exceptions import PayloadError, SettingError
from vtm_pin.numerics.dynamics import compute_M
from vtm_pin.physics.payload import (
    KEPT_PAYLOADS,
    Payload,
    attach_payload,
    attached,
    attachment,
    body_parameters,
    check_payload,
    describe_payload,
    inertia_matrix,
    payload_frame,
    payload_summary,
)
from vtm_pin.physics.robot import Drive, Robot, load_robot

#: Agreement of M, RNEA and ABA with the hand-built reference model, relative to the largest
#: entry: both add the same spatial inertias, only in another order and through another
#: placement product (URDF joint origin vs frame placement), so they differ by round-off
#: (about 1e-15); 1e-9 leaves a wide margin yet catches any misplaced mass or axis.
MATCH_RTOL = 1e-9
#: Smallest relative change of M the test payload must cause, so that the comparison with the
#: reference is not vacuous (a 2.7 kg payload on a 2-20 kg arm changes M by percents).
EFFECT_RTOL = 1e-3
#: Asymmetry allowed of the mass matrix built column by column from RNEA, relative to its
#: largest entry: round-off of the recursive algorithm (about 1e-15).
SYMMETRY_RTOL = 1e-10
#: Total mass grows by the payload's mass up to the round-off of summing a dozen bodies'
#: masses (a few ulps of the total).
MASS_RTOL = 1e-12
#: Random states compared per robot.
N_STATES = 5

#: An off-axis centre of mass [m] and a non-diagonal inertia about it [kg m^2] (principal
#: moments about 0.018, 0.026, 0.038: positive, and each below the sum of the other two).
COM = (0.031, -0.047, 0.083)
INERTIA = {"ixx": 0.021, "iyy": 0.034, "izz": 0.027, "ixy": 0.004, "ixz": -0.003, "iyz": 0.002}
MASS = 2.7  # [kg]

#: (robot, frame) pairs: "" is the tool frame (ur5: ``tool0``, a link fixed to wrist_3_link
#: by a rotated joint; panda: ``panda_hand_tcp``); the others are links mid-chain.
CASES = [("ur5", ""), ("panda", ""), ("ur5", "forearm_link"), ("panda", "panda_link5")]


def _reference_model(arm: Robot, link: str, payload: Payload) -> pin.Model:
    """The arm's URDF with the payload as a link fixed to ``link``, built by Pinocchio."""
    assert payload.inertia is not None
    urdf = Path(arm.source).read_text(encoding="utf-8")
    J = payload.inertia
    x, y, z = payload.com
    body = f"""
  <link name="vtm_test_payload">
    <inertial>
      <origin xyz="{x:.17g} {y:.17g} {z:.17g}" rpy="0 0 0"/>
      <mass value="{payload.mass:.17g}"/>
      <inertia ixx="{J[0, 0]:.17g}" iyy="{J[1, 1]:.17g}" izz="{J[2, 2]:.17g}"
               ixy="{J[0, 1]:.17g}" ixz="{J[0, 2]:.17g}" iyz="{J[1, 2]:.17g}"/>
    </inertial>
  </link>
  <joint name="vtm_test_payload_joint" type="fixed">
    <parent link="{link}"/>
    <child link="vtm_test_payload"/>
    <origin xyz="0 0 0" rpy="0 0 0"/>
  </joint>
"""
    end = urdf.rindex("</robot>")
    model = pin.buildModelFromXML(urdf[:end] + body + urdf[end:])
    model.armature = arm.model.armature.copy()  # the robot data's rotor inertias (not in URDFs)
    return model


def _random_states(
    model: pin.Model, seed: int
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """``N_STATES`` seeded (q, v, a, tau) within the joint limits [rad, rad/s, rad/s^2, N m]."""
    rng = np.random.default_rng(seed)
    for _ in range(N_STATES):
        q = rng.uniform(model.lowerPositionLimit, model.upperPositionLimit)
        yield (
            q,
            rng.normal(size=model.nv),
            rng.normal(size=model.nv),
            10 * rng.normal(size=model.nv),
        )


def _assert_close(actual: np.ndarray, expected: np.ndarray) -> None:
    scale = float(np.max(np.abs(expected)))
    np.testing.assert_allclose(actual, expected, rtol=MATCH_RTOL, atol=MATCH_RTOL * scale)


@pytest.mark.parametrize(("name", "frame"), CASES)
def test_dynamics_match_a_urdf_with_the_payload_link(name: str, frame: str) -> None:
    arm = robot(name)
    payload = Payload(MASS, COM, inertia_matrix(INERTIA), frame)
    link = payload_frame(arm, payload)
    assert arm.model.frames[arm.model.getFrameId(link)].type == pin.FrameType.BODY  # a link
    loaded = attach_payload(arm, payload).model
    reference = _reference_model(arm, link, payload)
    assert reference.nv == loaded.nv
    data, ref_data, bare_data = loaded.createData(), reference.createData(), arm.model.createData()
    for q, v, a, tau in _random_states(loaded, seed=7):
        M = compute_M(loaded, data, q)
        _assert_close(M, compute_M(reference, ref_data, q))
        bare = compute_M(arm.model, bare_data, q)
        assert np.max(np.abs(M - bare)) > EFFECT_RTOL * np.max(np.abs(bare))
        _assert_close(pin.rnea(loaded, data, q, v, a), pin.rnea(reference, ref_data, q, v, a))
        _assert_close(pin.aba(loaded, data, q, v, tau), pin.aba(reference, ref_data, q, v, tau))
    assert pin.computeTotalMass(loaded) == pytest.approx(
        pin.computeTotalMass(reference), rel=MASS_RTOL
    )


@st.composite
def _payloads(draw: st.DrawFn) -> Payload:
    """Mass in [0, 50] kg, centre of mass within 0.3 m, a random physical inertia or none."""
    mass = draw(st.floats(0.0, 50.0))
    com = (draw(st.floats(-0.3, 0.3)), draw(st.floats(-0.3, 0.3)), draw(st.floats(-0.3, 0.3)))
    if mass == 0.0 or draw(st.booleans()):
        return Payload(mass, com)
    # Second moments of the mass distribution along principal axes [kg m^2]; the principal
    # moments built from them obey the triangle inequality by construction.
    sx, sy, sz = (draw(st.floats(0.0, 1.0)) for _ in range(3))
    rotation = pin.exp3(np.array([draw(st.floats(-math.pi, math.pi)) for _ in range(3)]))
    inertia = rotation @ np.diag([sy + sz, sx + sz, sx + sy]) @ rotation.T
    return Payload(mass, com, inertia)


@settings(max_examples=30, deadline=None, derandomize=True, database=None)
@given(name=st.sampled_from(["ur5", "panda"]), payload=_payloads(), seed=st.integers(0, 2**32))
def test_mass_matrix_stays_spd_and_total_mass_grows_by_the_payload(
    name: str, payload: Payload, seed: int
) -> None:
    arm = robot(name)
    loaded = attach_payload(arm, payload).model
    data = loaded.createData()
    q = np.random.default_rng(seed).uniform(loaded.lowerPositionLimit, loaded.upperPositionLimit)
    zero = np.zeros(loaded.nv)
    gravity = pin.rnea(loaded, data, q, zero, zero)
    columns = [pin.rnea(loaded, data, q, zero, e) - gravity for e in np.eye(loaded.nv)]
    M = np.array(columns).T  # full matrix, independent of CRBA's upper triangle
    scale = float(np.max(np.abs(M)))
    assert np.max(np.abs(M - M.T)) <= SYMMETRY_RTOL * scale
    np.testing.assert_allclose(compute_M(loaded, data, q), M, atol=SYMMETRY_RTOL * scale)
    assert np.linalg.eigvalsh(0.5 * (M + M.T))[0] > 0.0
    total, bare = pin.computeTotalMass(loaded), pin.computeTotalMass(arm.model)
    assert total - bare == pytest.approx(payload.mass, abs=MASS_RTOL * total)


@settings(max_examples=40, deadline=None, derandomize=True, database=None)
@given(name=st.sampled_from(["ur10", "panda"]), payload=_payloads())
def test_a_payload_copys_body_parameters_are_its_models_own(name: str, payload: Payload) -> None:
    """The parameters :func:`attach_payload` keeps are those read from the loaded model, to
    the bit (the robot's, with the changed body's read again), whatever the payload."""
    arm = robot(name)
    loaded = attach_payload(arm, payload)
    kept = body_parameters(loaded)
    own = np.array([inertia.toDynamicParameters() for inertia in loaded.model.inertias])
    assert np.array_equal(kept, own)
    assert not kept.flags.writeable
    assert np.array_equal(
        body_parameters(arm), [i.toDynamicParameters() for i in arm.model.inertias]
    )


def test_a_payload_copy_records_what_was_added_to_which_body() -> None:
    """Its Attachment: the robot (by weak reference), the carrying joint, the mass and the
    centre of mass in that joint's frame, where the payload's placed inertia has its lever."""
    base = load_robot("ur5")  # its own cache, not the session's robot
    payload = Payload(MASS, COM, inertia_matrix(INERTIA), "wrist_2_link")
    made = attachment(attach_payload(base, payload))
    assert made is not None and made.robot() is base and made.mass == MASS
    frame = base.model.frames[base.model.getFrameId("wrist_2_link")]
    assert made.joint == frame.parentJoint
    assert made.lever == tuple(frame.placement.act(np.array(COM)).tolist())
    assert attachment(base) is None
    assert attachment(attach_payload(base, Payload(0.0, COM))) is None  # nothing added
    del base
    assert made.robot() is None  # the copy does not keep its robot alive


def test_zero_mass_leaves_the_dynamics_and_the_original_unchanged() -> None:
    arm = robot("ur5")
    data = arm.model.createData()
    before = [(float(i.mass), np.array(i.lever), np.array(i.inertia)) for i in arm.model.inertias]
    empty = attach_payload(arm, Payload(0.0, (0.1, -0.2, 0.3)))
    empty_data = empty.model.createData()
    for q, v, a, tau in _random_states(arm.model, seed=3):
        np.testing.assert_array_equal(
            compute_M(empty.model, empty_data, q), compute_M(arm.model, data, q)
        )
        np.testing.assert_array_equal(
            pin.rnea(empty.model, empty_data, q, v, a), pin.rnea(arm.model, data, q, v, a)
        )
        np.testing.assert_array_equal(
            pin.aba(empty.model, empty_data, q, v, tau), pin.aba(arm.model, data, q, v, tau)
        )
    heavy = attach_payload(arm, Payload(MASS, COM, inertia_matrix(INERTIA)))
    assert heavy.model is not arm.model
    after = [(float(i.mass), np.array(i.lever), np.array(i.inertia)) for i in arm.model.inertias]
    for (m0, c0, i0), (m1, c1, i1) in zip(before, after, strict=True):
        assert m0 == m1
        np.testing.assert_array_equal(c0, c1)
        np.testing.assert_array_equal(i0, i1)
    assert pin.computeTotalMass(heavy.model) > pin.computeTotalMass(arm.model)


def test_other_fields_and_armature_are_kept() -> None:
    arm = load_robot("ur5", drives={"elbow_joint": Drive(101.0, 3e-5)})
    loaded = attach_payload(arm, Payload(MASS, COM))
    np.testing.assert_array_equal(loaded.model.armature, arm.model.armature)
    assert loaded.model.armature[arm.joint_index("elbow_joint")] == pytest.approx(101.0**2 * 3e-5)
    assert (loaded.name, loaded.source, loaded.joints, loaded.tool_frame) == (
        arm.name,
        arm.source,
        arm.joints,
        arm.tool_frame,
    )
    np.testing.assert_array_equal(loaded.gear_ratio, arm.gear_ratio)


NAN = float("nan")
BAD = [
    (Payload(-1.0, (0, 0, 0)), "mass", "[0, 100000] kg"),
    (Payload(2e5, (0, 0, 0)), "mass", "[0, 100000] kg"),
    (Payload(math.inf, (0, 0, 0)), "mass", "finite mass"),
    (Payload(1.0, (NAN, 0, 0)), "com", "finite coordinates"),
    (Payload(1.0, (0, 0, 101.0)), "com", "within 100 m"),
    (Payload(1.0, (0, 0, 0), np.diag([-0.1, 0.2, 0.2])), "inertia", "positive semi-definite"),
    (Payload(1.0, (0, 0, 0), np.diag([0.1, 0.1, 0.5])), "inertia", "triangle inequality"),
    (Payload(1.0, (0, 0, 0), np.diag([NAN, 0.1, 0.1])), "inertia", "nan or inf"),
    (Payload(1.0, (0, 0, 0), np.diag([2e5, 2e5, 2e5])), "inertia", "above 100000 kg m^2"),
    (
        Payload(1.0, (0, 0, 0), np.array([[1, 0.5, 0], [0, 1, 0], [0, 0, 1.0]])),
        "inertia",
        "not symmetric",
    ),
    (Payload(0.0, (0, 0, 0), np.eye(3)), "inertia", "mass 0 kg"),
    (Payload(1.0, (0, 0, 0), frame="no_such_frame"), "frame", "frames: universe, world"),
    (Payload(1.0, (0, 0, 0), frame="base_link"), "frame", "fixed to the ground"),
]


def test_attached_keeps_one_robot_per_payload_equal_to_the_bit() -> None:
    """A study's payload classes share a robot (its Data, its reduced models); anything that
    could change a figure (another mass, a centre of mass of -0.0, another frame) gets its own,
    equal to a fresh attach_payload's; a refused payload is not kept."""
    base = load_robot("ur10")  # its own cache, not the session's robot
    payload = Payload(4.0, (0.0, 0.0, 0.05))
    first = attached(base, payload)
    assert attached(base, Payload(4.0, (0.0, 0.0, 0.05))) is first
    fresh = attach_payload(base, payload)
    assert first is not fresh and first == fresh
    assert first.model.inertias[6] == fresh.model.inertias[6]
    others = [
        Payload(4.0 + 1e-12, (0.0, 0.0, 0.05)),
        Payload(4.0, (-0.0, 0.0, 0.05)),
        Payload(4.0, (0.0, 0.0, 0.05), np.diag([1e-3, 1e-3, 1e-3])),
        Payload(4.0, (0.0, 0.0, 0.05), frame="wrist_3_link"),
    ]
    assert len({id(attached(base, other)) for other in others} | {id(first)}) == 5
    with pytest.raises(PayloadError):
        attached(base, Payload(-1.0, (0.0, 0.0, 0.0)))
    with pytest.raises(PayloadError):  # refused again, not found kept
        attached(base, Payload(-1.0, (0.0, 0.0, 0.0)))
    for k in range(KEPT_PAYLOADS):  # a drawn payload per case: the oldest is let go
        attached(base, Payload(float(k), (0.0, 0.0, 0.0)))
    assert attached(base, payload) is not first


@pytest.mark.parametrize(("payload", "key", "phrase"), BAD)
def test_bad_payloads_are_refused_naming_the_key(payload: Payload, key: str, phrase: str) -> None:
    with pytest.raises(PayloadError) as caught:
        attach_payload(robot("ur5"), payload)
    assert isinstance(caught.value, SettingError)
    assert caught.value.key == key
    assert phrase in caught.value.problem
    assert "\n" not in str(caught.value)


def test_unknown_frame_lists_the_frames() -> None:
    with pytest.raises(PayloadError) as caught:
        check_payload(robot("panda"), Payload(1.0, (0, 0, 0), frame="tool0"))
    assert "panda_hand_tcp" in caught.value.problem
    assert "panda_link7" in caught.value.problem


def test_rounded_inertias_within_the_slack_are_accepted() -> None:
    # A flat plate's moments (I_z = I_x + I_y) rounded up in the 4th digit.
    plate = Payload(1.0, (0, 0, 0), np.diag([0.1, 0.1, 0.2001]))
    assert check_payload(robot("ur5"), plate) == "tool0"


def test_a_rounded_moment_just_below_zero_is_attached() -> None:
    # -1e-5 kg m^2 is within the slack (1e-3 of the largest moment, 0.1 kg m^2); Pinocchio's
    # own Inertia constructor would refuse it.
    rounded = Payload(1.0, (0, 0, 0.05), np.diag([-1e-5, 0.1, 0.1]))
    bare = pin.computeTotalMass(robot("ur5").model)
    loaded = attach_payload(robot("ur5"), rounded)
    assert pin.computeTotalMass(loaded.model) == pytest.approx(bare + 1.0, rel=MASS_RTOL)


@pytest.mark.parametrize(
    ("value", "key", "phrase"),
    [
        ("heavy", "mass", "not a number"),
        (True, "mass", "not a number"),
    ],
)
def test_malformed_mass_is_refused_at_construction(value: object, key: str, phrase: str) -> None:
    with pytest.raises(PayloadError, match=phrase) as caught:
        Payload(value, (0, 0, 0))  # type: ignore[arg-type]
    assert caught.value.key == key


def test_malformed_com_and_inertia_are_refused_at_construction() -> None:
    with pytest.raises(PayloadError, match="not 3 numbers") as caught:
        Payload(1.0, (0, 0))  # type: ignore[arg-type]
    assert caught.value.key == "com"
    with pytest.raises(PayloadError, match="not a number") as caught:
        Payload(1.0, (0, 0, "x"))  # type: ignore[arg-type]
    assert caught.value.key == "com"
    with pytest.raises(PayloadError, match="3 x 3") as caught:
        Payload(1.0, (0, 0, 0), np.eye(2))
    assert caught.value.key == "inertia"


def test_inertia_matrix_follows_the_urdf_convention() -> None:
    np.testing.assert_array_equal(
        inertia_matrix(INERTIA),
        [[0.021, 0.004, -0.003], [0.004, 0.034, 0.002], [-0.003, 0.002, 0.027]],
    )
    np.testing.assert_array_equal(
        inertia_matrix({"ixx": 1, "iyy": 2, "izz": 3}), np.diag([1.0, 2.0, 3.0])
    )


@pytest.mark.parametrize(
    ("values", "key", "phrase"),
    [
        ({"iyy": 1.0, "izz": 1.0}, "inertia.ixx", "missing"),
        ({"ixx": 1.0, "iyy": 1.0, "izz": 1.0, "iyx": 0.0}, "inertia", "unknown entry 'iyx'"),
        ({"ixx": "big", "iyy": 1.0, "izz": 1.0}, "inertia.ixx", "not a number"),
    ],
)
def test_inertia_matrix_refuses_malformed_entries(values: dict, key: str, phrase: str) -> None:
    with pytest.raises(PayloadError) as caught:
        inertia_matrix(values)
    assert caught.value.key == key
    assert phrase in caught.value.problem


def test_payload_is_immutable_and_compares_by_value() -> None:
    source = inertia_matrix(INERTIA)
    payload = Payload(MASS, COM, source)
    source[0, 0] = 99.0  # the payload keeps its own copy
    assert payload.inertia is not None
    assert payload.inertia[0, 0] == INERTIA["ixx"]
    with pytest.raises(ValueError, match="read-only"):
        payload.inertia[0, 0] = 1.0
    twin = Payload(MASS, list(COM), inertia_matrix(INERTIA))  # type: ignore[arg-type]
    assert twin == payload
    assert hash(twin) == hash(payload)
    assert Payload(MASS, COM) != payload
    assert Payload(MASS, COM) == Payload(MASS, COM)


def test_describe_payload() -> None:
    point = Payload(5.0, (0.0, -0.0, 0.05))
    assert describe_payload(point, "tool0") == (
        "Payload 5 kg rigidly attached to frame tool0, centre of mass at [0, 0, 0.05] m in that "
        "frame, a point mass (no rotational inertia)."
    )
    body = describe_payload(Payload(MASS, COM, inertia_matrix(INERTIA)), "panda_hand_tcp")
    assert body.startswith("Payload 2.7 kg rigidly attached to frame panda_hand_tcp, ")
    assert "[0.031, -0.047, 0.083] m" in body
    assert "ixx 0.021, iyy 0.034, izz 0.027, ixy 0.004, ixz -0.003, iyz 0.002 kg m^2" in body
    assert "point mass" not in body
    assert "\n" not in body


def test_payload_summary_is_json_ready() -> None:
    units = {"mass": "kg", "com": "m", "inertia": "kg m^2"}
    point = payload_summary(Payload(5.0, (0.0, 0.0, 0.05)), "tool0")
    assert json.loads(json.dumps(point, allow_nan=False)) == {
        "mass": 5.0,
        "com": [0.0, 0.0, 0.05],
        "inertia": None,
        "frame": "tool0",
        "units": units,
    }
    body = payload_summary(Payload(MASS, COM, inertia_matrix(INERTIA)), "tool0")
    decoded = json.loads(json.dumps(body, allow_nan=False))
    assert decoded["inertia"] == inertia_matrix(INERTIA).tolist()
    assert decoded["com"] == list(COM)
    assert decoded["units"] == units

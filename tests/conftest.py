"""Shared fixtures: robots are loaded once per session; numerics are strict."""

from __future__ import annotations

import importlib
import pkgutil
import signal
import sys
from pathlib import Path

import numpy as np
import pytest

import vtm_pin
from vtm_pin import Problem, Robot, SimulationResult, load_robot, simulate
from vtm_pin.physics import body_kernel
from vtm_pin.physics.brakes import Brake
from vtm_pin.physics.friction import Coulomb
from vtm_pin.physics.stop import Stop

#: A test's two paths where a compiled kernel may run (parameter ``compiled``, to set
#: ``body_kernel.AVAILABLE`` to): NumPy, the default and the fallback, and the compiled kernels
#: of the ``fast`` extra.
KERNEL_PATHS = pytest.mark.parametrize(
    "compiled",
    [
        False,
        pytest.param(
            True,
            marks=pytest.mark.skipif(not body_kernel.AVAILABLE, reason="Numba is not installed"),
        ),
    ],
    ids=["numpy", "compiled"],
)

# Every module of the package, imported before any test runs. Hypothesis draws from the
# constants of the project modules already imported ("local constants", Hypothesis 6.1xx), so
# without this a property's derandomized draws depended on which tests ran before it in the
# same worker (a test importing vtm_pin.cli first changed them; a drawn failure showed in
# some orders only).
for _module in pkgutil.walk_packages(vtm_pin.__path__, "vtm_pin."):
    importlib.import_module(_module.name)

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ROOT / "scenarios"
sys.path.insert(0, str(Path(__file__).resolve().parent))

#: The joints of the UR arms, in model order.
UR_JOINTS = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)

_CACHE: dict[str, Robot] = {}


def robot(name: str) -> Robot:
    """A robot loaded once per test session (tests must not modify it)."""
    if name not in _CACHE:
        _CACHE[name] = load_robot(name)
    return _CACHE[name]


@pytest.fixture(autouse=True)
def _default_sigint():
    """Ctrl-C as at a terminal: the tests' subprocesses must not inherit an ignored SIGINT.

    A test run started in the background of a non-interactive shell (``pytest &``) has SIGINT
    ignored (POSIX), Python keeps it so and its children inherit it: ``vtm-pin study`` started
    by a test then ignored the Ctrl-C the test sent and ran to the end (the Ctrl-C test of
    tests/test_study_store.py failed with exit status 0 on pytest-xdist workers).
    """
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(autouse=True)
def _strict_numpy():
    with np.errstate(divide="raise", over="raise", invalid="raise"):
        yield


#: Built to trigger every transition of the brake state machine on joint 1 of the pendulum:
#: from q = (0, 1.2, 0) rad, v = (2, 0, 0) rad/s the brake (slide 300, static 400 N m) must
#: reverse three times, stick, slip, stick and slip again within 3 s.
RESLIP_BRAKE = Brake("joint1", friction=Coulomb(300.0, 400.0))
Q0_RESLIP, V0_RESLIP = np.array([0.0, 1.2, 0.0]), np.array([2.0, 0.0, 0.0])  # [rad], [rad/s]
RESLIP_KINDS = ["engage", "reverse", "reverse", "reverse", "stick", "slip", "stick", "slip"]


def run_reslip(integrator, duration: float = 3.0) -> SimulationResult:
    """The re-slip pendulum run with the given integrator."""
    q0, v0 = Q0_RESLIP, V0_RESLIP
    problem = Problem(robot("planar_3r"), q0, v0, duration, brakes=(RESLIP_BRAKE,), stop=Stop(0.0))
    return simulate(problem, integrator)


def viscous_and_shorted(raw: dict, ramped: bool = False) -> dict:
    """A UR10 scenario (parsed) with two viscous brakes and two motors shorted on drop-out.

    ``ramped``: its brakes' normal force also ramps up over 20 ms, and they engage at staggered
    times (30-60 ms), which makes it no plain stop.
    """
    raw = dict(raw)
    brakes = {joint: dict(brake) for joint, brake in raw["brakes"].items()}
    for k, brake in enumerate(brakes.values()):
        if ramped:
            brake.update(delay=0.03 + 0.006 * k, ramp=0.02)
        if k in (1, 3):
            brake.update(friction="viscous", viscous_velocity=400.0)
    raw["brakes"] = brakes
    raw["drives"] = {
        joint: {"gear_ratio": 101, "rotor_inertia": 1.0e-4 if k < 3 else 3.0e-5}
        | ({"short_circuit_torque": 0.5, "short_circuit_speed": 300.0} if k in (0, 2) else {})
        for k, joint in enumerate(brakes)
    }
    return raw

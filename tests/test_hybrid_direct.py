"""The batched engine's brake decisions without trial phases: the same numbers, bit for bit.

In the batched engine (full model, no drive acting, no frame constraint) the hybrid loop answers
the brakes' trial lock sets from the full model's M and b directly
(``_Hybrid.holding_torque``, ``_Hybrid.accelerations``) instead of building a trial
:class:`~vtm_pin.core.phase.Phase`. Tolerance: none. The two compute the same sums in the same
order, so every bit agrees; any difference would change which brake decisions are taken near a
threshold.
"""

from __future__ import annotations

import numpy as np
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

import vtm_pin as vp
from vtm_pin.core.simulation import _Hybrid
from vtm_pin.physics.brakes import BrakeMode
from vtm_pin.scene.scenario import SCENARIOS_DIR

_MODES = [BrakeMode.FREE, BrakeMode.FORWARD, BrakeMode.BACKWARD, BrakeMode.STUCK]


def _problem() -> vp.Problem:
    raw = yaml.safe_load((SCENARIOS_DIR / "ur10_annex_b.yaml").read_text())
    raw["drives"] = {  # shorted motors too, so that their torques enter the sums
        j: {"gear_ratio": 101, "rotor_inertia": 1e-4}
        | {"short_circuit_torque": 0.4, "short_circuit_speed": 150.0}
        for j in vp.build_scenario(raw, source="t", base_dir=SCENARIOS_DIR).problem.robot.joints
    }
    return vp.build_scenario(raw, source="test", base_dir=SCENARIOS_DIR, name="direct").problem


PROBLEM = _problem()


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(-3.0, 3.0), min_size=6, max_size=6),
    st.lists(st.floats(-2.0, 2.0), min_size=6, max_size=6),
    st.lists(st.sampled_from(_MODES), min_size=6, max_size=6),
    st.lists(st.booleans(), min_size=6, max_size=6),
    st.lists(st.booleans(), min_size=6, max_size=6),
    st.floats(0.0, 0.5),
)
def test_trial_lock_sets_are_answered_bit_for_bit_as_a_trial_phase(
    q: list[float],
    v: list[float],
    modes: list[BrakeMode],
    shorted: list[bool],
    locked: list[bool],
    t: float,
) -> None:
    """Holding torques and accelerations, direct and through a trial phase, over random states,
    brake modes, shorted motors and lock sets (none locked to all locked)."""
    p = PROBLEM
    h = _Hybrid(p.robot, np.array(q), np.array(v), p.brakes, p.stop, "kkt", reduced=False)
    h.drop_out(slice(None))
    h.dynamic_on[:] = np.array(shorted) & h.dynamic.present
    for i in range(p.robot.nv):
        h.machine.engaged[i] = 0.0
        h.machine.modes[i] = modes[i]
    trial_set = [i for i in range(p.robot.nv) if locked[i]]
    h.locked = [i for i in trial_set if modes[i] is BrakeMode.STUCK]
    h.v[trial_set] = 0.0
    assert h._undriven_full()
    direct = h.holding_torque(t, trial_set)
    trial = h.new_phase(trial_set)
    assert np.array_equal(direct, trial.holding_torque(t, trial.pack(h.q, h.v, h.extras)))
    a_direct = h.accelerations(t)
    phase = h.new_phase()
    assert np.array_equal(a_direct, phase.accelerations(t, phase.pack(h.q, h.v, h.extras)))

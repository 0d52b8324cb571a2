"""benchmarks/study_profile.py: how py-spy's samples are shared out among a case's parts."""

import inspect
import sys

from conftest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))
from study_profile import BUILD_STEPS, PARTS, PLAIN, RESUMED_BY, attribute

from vtm_pin.core import batch
from vtm_pin.outputs import figures
from vtm_pin.scene import scenario
from vtm_pin.study import runner

TOP = "<module> (study_profile.py:9);_measured (study_profile.py:3);run_cases (runner.py:1)"
RUN = f"{TOP};_run_group (runner.py:2);run_many (batch.py:3);_run_batch (batch.py:4)"


def stack(*frames: str) -> str:
    return ";".join(f"{name} (x.py:{k})" for k, name in enumerate(frames))


def test_each_sample_goes_to_the_first_part_it_holds_and_the_shares_add_up():
    lines = [
        # the report of a case that ended while a lane was resuming its loop: report first
        f"{RUN};{stack('BatchEngine.run', 'BatchEngine._sync', 'BatchEngine.advance')};"
        f"{stack('_Run.advance', 'hybrid_run', '_complete_many', 'stopping')} 3\n",
        f"{RUN};{stack('BatchEngine.run', 'BatchEngine._sync', 'BatchEngine.advance')};"
        f"{stack('_Run.advance', 'hybrid_run')} 5\n",
        f"{RUN};{stack('BatchEngine.run', 'BatchEngine._hand', 'BatchEngine.advance')};"
        f"{stack('_Run.advance')} 2\n",
        # a plain stop's records, made under the lanes' rests: the hybrid loop's
        f"{RUN};{stack('BatchEngine.run', 'BatchEngine._settle_rests', 'BatchEngine._conclude')};"
        f"{stack('PlainStop.result', '_Trace.result')} 4\n",
        f"{RUN};{stack('BatchEngine.run', 'BatchEngine._round', '_Dynamics.accelerations')} 7\n",
        f"{RUN};{stack('BatchEngine.run', 'BatchEngine._dense_samples', '_grid_times')} 4\n",
        f"{RUN};{stack('BatchEngine.run', 'BatchEngine._dense_samples')} 6\n",
        f"{RUN};{stack('BatchEngine.run', 'BatchEngine._round')} 8\n",
        f"{TOP};{stack('build_scenario', 'load_robot')} 9\n",
        f"{TOP};{stack('_Poses.solve', 'solve_variant_poses')} 1\n",
        f"{RUN};{stack('_simulate_one', 'simulate', 'hybrid_run')} 2\n",
        f"{TOP};{stack('dict')} 1\n",  # in run_cases, in no part
        # not measured: the warm-up, an import inside the batch, a malformed line
        "<module> (study_profile.py:9);_child (study_profile.py:4);run_cases (r.py:1) 50\n",
        f"{RUN};{stack('_Dynamics.accelerations', '_find_and_load')} 20\n",
        "garbage\n",
    ]
    profile = attribute(lines)
    assert profile.total == 3 + 5 + 2 + 4 + 7 + 4 + 6 + 8 + 9 + 1 + 2 + 1
    assert profile.parts == {
        "report": 3,
        "hybrid loop": 11,
        "dynamics": 7,
        "lanes": 4,
        "dense output": 6,
        "stepping": 8,
        "build": 10,
        "scalar": 2,
        "other": 1,
    }
    assert sum(profile.parts.values()) == profile.total
    assert profile.resumed == {
        RESUMED_BY["BatchEngine._sync"]: 5,
        RESUMED_BY["BatchEngine._hand"]: 2,
        PLAIN["PlainStop.result"]: 4,
    }
    assert profile.build == {BUILD_STEPS["build_scenario"]: 9, BUILD_STEPS["_Poses.solve"]: 1}


def test_every_frame_the_profile_looks_for_is_a_function_of_the_package():
    """A renamed function would silently move its samples to another part: name them all."""
    defined = {
        name
        for module in (batch, runner, scenario, figures)
        for _, obj in inspect.getmembers(module)
        for name in _qualnames(obj)
    }
    wanted = {frame for _, _, frames in PARTS for frame in frames}
    wanted |= set(RESUMED_BY) | set(BUILD_STEPS) | set(PLAIN) | {"BatchEngine.advance"}
    assert wanted - defined == set()


def _qualnames(obj: object) -> list[str]:
    """A module member's qualified name, and its methods' if it is a class."""
    if inspect.isclass(obj):
        return [obj.__qualname__] + [
            f.__qualname__ for _, f in inspect.getmembers(obj, inspect.isfunction)
        ]
    return [getattr(obj, "__qualname__", "")] if inspect.isfunction(obj) else []

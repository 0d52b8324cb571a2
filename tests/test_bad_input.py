"""Generated bad input: every class gives one line on stderr, status 1 (2 for usage), no output.

From a fixed seed, the generator below mutates the shipped scenarios and robots into inputs
that must be refused: wrong types, huge integers, NaN and infinities, out-of-range and
negative values, unknown keys of mixed types, deep nesting, YAML alias bombs, bytes that are
not UTF-8, truncated YAML, semantic errors (unknown joints, events outside the run), broken
URDFs and robot data files, bad command-line options, an output folder under a regular file,
and errors found only while simulating (a docking away from its target, dop853 past
``max_steps``), these with tiny durations. Each input goes through ``vtm_pin.cli.main`` and
must give exactly one stderr line that names the file and the key (where there is one), and
leave the folder as it was: no output, no staging folder.
"""

from __future__ import annotations

import math
import random
import re
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import pytest
import yaml
from conftest import ROOT, SCENARIOS

from vtm_pin.cli import main
from vtm_pin.exceptions import excerpt

SEED = 20261122
BASES = {path.stem: yaml.safe_load(path.read_text()) for path in sorted(SCENARIOS.glob("*.yaml"))}
#: Bases whose robot loads in milliseconds (example-robot-data models take ~0.5 s each): the
#: inputs that pass the schema use these, so that the default run stays short.
FAST = ["pendulum3r", "rx160l_estop_cat0", "rx160l_estop_cat1", "rx160l_paper_locks"]
URDF = (ROOT / "robots" / "planar_3r.urdf").read_text()
SMALL = {  # a valid scenario for planar_3r that runs in milliseconds
    "robot": "bot.urdf",
    "initial": {"q": [0.5, 0.5, 0.5]},
    "duration": 0.01,
    "integrator": {"method": "rk4", "dt": 0.001},
}
#: Values that no number key accepts: wrong types, NaN, infinities, integers too large for a
#: float, and magnitudes beyond every bound of the schema.
BAD_NUMBERS: list[Any] = [
    "abc",
    "",
    [1.0],
    {"a": 1},
    None,
    True,
    math.nan,
    math.inf,
    -math.inf,
    10**400,
    -(10**400),
    1e308,
    -1e308,
    1e12,
    -1e4,
]
BAD_STRINGS: list[Any] = [123, 1.5, [], ["a"], {"a": "b"}, None, True]


@dataclass(frozen=True)
class Case:
    """One bad input: files to write, the command line, and what the error must say.

    ``{tmp}`` in a file name, argument or expected text is the test's folder.
    """

    name: str
    args: list[str]
    files: dict[str, bytes] = field(default_factory=dict)
    status: int = 1
    source: str = "{tmp}/s.yaml"
    key: str = ""


def dump(doc: Any) -> bytes:
    return yaml.safe_dump(doc, sort_keys=False, allow_unicode=True).encode()


def run_args(*extra: str) -> list[str]:
    return ["run", "{tmp}/s.yaml", "--out", "{tmp}/out", *extra]


def scenario_case(name: str, doc: Any, key: str = "", **files: bytes) -> Case:
    return Case(name, run_args(), {"s.yaml": dump(doc), **files}, key=key)


def leaves(doc: Any, path: tuple[Any, ...] = ()) -> list[tuple[tuple[Any, ...], Any]]:
    """Every (path, value) of the leaves of a parsed document."""
    if isinstance(doc, dict):
        return [item for k, v in doc.items() for item in leaves(v, (*path, k))]
    if isinstance(doc, list):
        return [item for i, v in enumerate(doc) for item in leaves(v, (*path, i))]
    return [(path, doc)]


def mappings(doc: Any, path: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Paths of every mapping of a parsed document."""
    out = [path] if isinstance(doc, dict) else []
    children = (
        doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else []
    )
    return out + [p for k, v in children for p in mappings(v, (*path, k))]


def replaced(doc: Any, path: tuple[Any, ...], value: Any) -> Any:
    """A deep copy of ``doc`` with the value at ``path`` replaced."""
    if not path:
        return value
    if isinstance(doc, dict):
        return {k: replaced(v, path[1:], value) if k == path[0] else v for k, v in doc.items()}
    return [replaced(v, path[1:], value) if i == path[0] else v for i, v in enumerate(doc)]


def at(doc: Any, path: tuple[Any, ...]) -> Any:
    for part in path:
        doc = doc[part]
    return doc


def key_of(path: tuple[Any, ...]) -> str:
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else (f".{excerpt(part)}" if out else part)
    return out


def pick_base(rng: random.Random, fast: bool = False) -> tuple[str, Any]:
    name = rng.choice(FAST if fast else sorted(BASES))
    return name, yaml.safe_load(yaml.safe_dump(BASES[name]))  # a copy


# --- scenario mutations -----------------------------------------------------------------


def bad_number(rng: random.Random) -> Case:
    name, doc = pick_base(rng)
    numbers = [
        (p, v) for p, v in leaves(doc) if isinstance(v, (int, float)) and not isinstance(v, bool)
    ]
    path, _ = rng.choice(numbers)
    value = rng.choice(BAD_NUMBERS)
    return scenario_case(f"number-{name}-{key_of(path)}", replaced(doc, path, value), key_of(path))


def bad_string_type(rng: random.Random) -> Case:
    name, doc = pick_base(rng)
    strings = [(p, v) for p, v in leaves(doc) if isinstance(v, str)]
    path, _ = rng.choice(strings)
    doc = replaced(doc, path, rng.choice(BAD_STRINGS))
    return scenario_case(f"string-type-{name}-{key_of(path)}", doc, key_of(path))


def garbage(rng: random.Random) -> str:
    length = rng.choice([1, 5, 80, 300, 5000])
    alphabet = "abcxyz_-./ äö\n\t\"'é€"
    return "".join(rng.choice(alphabet) for _ in range(length))


def bad_name(rng: random.Random) -> Case:
    """A name that names nothing: robot, joint, frame, rule, method."""
    name, doc = pick_base(rng, fast=True)
    text = "zz" + garbage(rng)
    kind = rng.choice(["robot", "transition", "method", "lock", "tool_frame", "brake", "frame"])
    if kind == "robot":
        return scenario_case(f"name-robot-{name}", {**doc, "robot": text}, "robot")
    if kind == "transition":
        return scenario_case(f"name-rule-{name}", {**doc, "transition": text}, "transition")
    if kind == "method":
        doc["integrator"] = {"method": text}
        return scenario_case(f"name-method-{name}", doc, "integrator.method")
    if kind == "lock":
        doc["events"] = [{"t": 0.0, "lock": [text]}]
        return scenario_case(f"name-lock-{name}", doc, "events[0].lock")
    if kind == "tool_frame":
        return scenario_case(f"name-tool-{name}", {**doc, "tool_frame": text}, "tool_frame")
    if kind == "brake" and "brakes" in doc:
        doc["brakes"][text] = {"ideal": True}
        return scenario_case(f"name-brake-{name}", doc, f"brakes.{excerpt(text)}")
    doc["events"] = [{"t": 0.0, "activate": [{"type": "dock", "frame_a": text}]}]
    doc.pop("brakes", None)
    return scenario_case(f"name-frame-{name}", doc, "events[0].activate[0]")


def unknown_keys(rng: random.Random) -> Case:
    name, doc = pick_base(rng)
    path = rng.choice(mappings(doc))
    node = at(doc, path)
    odd = rng.choice([1, 2.5, True, None, -3])
    if rng.random() < 0.6:  # a key that is not a string, beside a string one
        node[odd] = "a"
        node["foo"] = "b"
        return scenario_case(f"keys-mixed-{name}-{key_of(path)}", doc, key_of(path))
    node["zz_unknown"] = "b"
    return scenario_case(f"keys-unknown-{name}-{key_of(path)}", doc, key_of((*path, "zz_unknown")))


def deep_nesting(rng: random.Random) -> Case:
    name, doc = pick_base(rng)
    path, _ = rng.choice(leaves(doc))
    depth = rng.choice([33, 100, 1000, 5000])
    nested = "[" * depth + "]" * depth if rng.random() < 0.5 else "{a: " * depth + "1" + "}" * depth
    text = dump(replaced(doc, path, "@@DEEP@@")).decode()
    text = re.sub(r"""'@@DEEP@@'|"@@DEEP@@"|@@DEEP@@""", lambda _: nested, text)
    return Case(f"deep-{depth}-{name}", run_args(), {"s.yaml": text.encode()})


def alias_bomb(rng: random.Random) -> Case:
    name, doc = pick_base(rng)
    width, levels = rng.randint(4, 10), rng.randint(7, 12)
    lines = [f"  - &a0 [{', '.join(['lol'] * width)}]"]
    lines += [f"  - &a{i} [{', '.join([f'*a{i - 1}'] * width)}]" for i in range(1, levels)]
    if rng.random() < 0.2:
        lines = ["  - &self [1, *self]"]  # an alias inside the collection it names
    doc.pop("assumptions", None)
    text = dump(doc).decode() + "assumptions:\n" + "\n".join(lines) + "\n"
    return Case(f"bomb-{width}x{levels}-{name}", run_args(), {"s.yaml": text.encode()})


def not_utf8(rng: random.Random) -> Case:
    name, doc = pick_base(rng)
    text = dump({**doc, "description": "Stäubli RX160L, 1.5 m/s² … ok"}).decode()
    kind = rng.choice(["random", "latin1", "utf16", "utf16-no-bom", "nul", "control"])
    if kind == "random":
        data = bytearray(rng.randrange(256) for _ in range(rng.randint(1, 3000)))
        data.insert(rng.randrange(len(data) + 1), 0xFF)
    elif kind == "latin1":
        data = bytearray(text.replace("…", "...").replace("²", "2").encode("latin-1"))
    elif kind == "utf16":
        data = bytearray(text.encode(rng.choice(["utf-16", "utf-16-be"])))
        if not data.startswith((b"\xff\xfe", b"\xfe\xff")):
            data[0:0] = b"\xfe\xff"
    elif kind == "utf16-no-bom":
        data = bytearray(text.encode("utf-16-le"))
    else:
        char = "\x00" if kind == "nul" else rng.choice("\x01\x07\x1b\x7f")
        i = rng.randrange(len(text))
        data = bytearray((text[:i] + char + text[i:]).encode())
    return Case(f"encoding-{kind}-{name}", run_args(), {"s.yaml": bytes(data)})


def truncated(rng: random.Random) -> Case:
    name, doc = pick_base(rng)
    if rng.random() < 0.5:  # cut inside the outer flow mapping: never valid YAML
        flow = yaml.safe_dump(doc, sort_keys=False, default_flow_style=True).rstrip()
        cut = rng.randint(1, len(flow) - 1)
        return Case(f"truncated-flow-{name}", run_args(), {"s.yaml": flow[:cut].encode()})
    required = rng.choice(["robot", "initial", "duration"])
    if required == "initial" and "annex_b" in doc:  # annex_b computes the initial state
        required = "duration"
    doc.pop(required)
    return scenario_case(f"truncated-{required}-{name}", doc, required)


SEMANTIC = [
    "q-length",
    "v-joint",
    "event-late",
    "event-empty",
    "dt-long",
    "dt-tiny",
    "rtol-rk4",
    "dt-dop853",
    "stop-late",
    "cat1-limit",
    "brakes-no-stop",
    "drive-joint",
]


def semantic(rng: random.Random) -> Case:
    """Values the schema allows that the robot or the run cannot have."""
    name, doc = pick_base(rng, fast=True)
    joint = "joint1" if name == "pendulum3r" else "joint_1"
    duration, n = doc["duration"], len(doc["initial"]["q"])
    kind = rng.choice(SEMANTIC)
    if kind == "q-length":
        doc["initial"]["q"], key = [0.0] * (n + 1), "initial.q"
    elif kind == "v-joint":
        doc["initial"]["v"], key = {"nope": 1.0}, "initial.v"
    elif kind == "event-late":
        doc["events"], key = [{"t": duration + 1.0, "lock": [joint]}], "events[0].t"
    elif kind == "event-empty":
        doc["events"], key = [{"t": 0.0}], "events[0]"
    elif kind == "dt-long":
        doc["integrator"], key = {"method": "rk4", "dt": 2.0 * duration}, "integrator.dt"
    elif kind == "dt-tiny":
        doc["integrator"], key = {"method": "euler", "dt": 1e-12}, "integrator.dt"
    elif kind == "rtol-rk4":
        doc["integrator"], key = {"method": "rk4", "rtol": 1e-6}, "integrator.rtol"
    elif kind == "dt-dop853":
        doc["integrator"], key = {"method": "dop853", "dt": 1e-3}, "integrator.dt"
    elif kind == "stop-late":
        doc["stop"], key = {"t": duration + 1.0}, "stop.t"
    elif kind == "cat1-limit":
        doc["stop"], key = {"category": 1, "torque_limit": 10.0}, "stop"  # no ramp_time
    elif kind == "brakes-no-stop":
        doc.pop("stop", None)
        doc["brakes"], key = {joint: {"ideal": True}}, "brakes"
    else:
        doc["drives"], key = {"nope": {"gear_ratio": 2}}, "drives.nope"
    return scenario_case(f"semantic-{kind}-{name}", doc, key)


# --- robots and robot data files ----------------------------------------------------------


def bad_urdf(rng: random.Random) -> Case:
    mass, inertia = (
        '<mass value="108"/>',
        'ixx="9.36" ixy="0" ixz="0" iyy="9.36" iyz="0" izz="0.72"',
    )
    last = URDF.rfind(mass)
    last_inertia = URDF.rfind(inertia)
    kinds: dict[str, Callable[[], str]] = {
        "mass-nan": lambda: URDF.replace(mass, '<mass value="nan"/>', 1),
        "mass-negative": lambda: URDF[:last] + '<mass value="-1"/>' + URDF[last + len(mass) :],
        "mass-huge": lambda: URDF.replace(mass, '<mass value="1e300"/>', 1),
        "zero-last-link": lambda: (
            URDF[:last]
            + '<mass value="0"/>'
            + URDF[last + len(mass) : last_inertia]
            + 'ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"'
            + URDF[last_inertia + len(inertia) :]
        ),
        "not-pd": lambda: URDF.replace('ixy="0"', 'ixy="50"', 1),
        "triangle": lambda: URDF.replace('izz="0.72"', 'izz="30"', 1),
        "inertia-nan": lambda: URDF.replace('ixx="9.36"', 'ixx="nan"', 1),
        "offset-huge": lambda: URDF.replace('xyz="0 0 -0.5"', 'xyz="0 0 -1e300"', 1),
        "no-joints": lambda: '<robot name="r"><link name="base"/></robot>',
        "broken-xml": lambda: URDF[: rng.randint(10, len(URDF) - 30)],
        "continuous": lambda: URDF.replace('type="revolute"', 'type="continuous"', 1),
        "latin1": lambda: URDF.replace("<robot", "<!-- Stäubli --><robot", 1),
        "utf16": lambda: URDF,
    }
    kind = rng.choice(sorted(kinds))
    text = kinds[kind]()
    data = text.encode("latin-1" if kind == "latin1" else "utf-16" if kind == "utf16" else "utf-8")
    return Case(
        f"urdf-{kind}",
        run_args(),
        {"s.yaml": dump(SMALL), "bot.urdf": data},
        key="robot",
    )


def bad_side_file(rng: random.Random) -> Case:
    kinds: dict[str, tuple[bytes, str]] = {
        "gear-negative": (b"drives:\n  joint1: {gear_ratio: -5}\n", "drives.joint1.gear_ratio"),
        "rotor-negative": (
            b"drives:\n  joint2: {rotor_inertia: -1}\n",
            "drives.joint2.rotor_inertia",
        ),
        "gear-nan": (b"drives:\n  joint1: {gear_ratio: .nan}\n", "drives.joint1.gear_ratio"),
        "gear-huge": (
            b"drives:\n  joint3: {gear_ratio: " + b"9" * 400 + b"}\n",
            "drives.joint3.gear_ratio",
        ),
        "gear-text": (b"drives:\n  joint1: {gear_ratio: fast}\n", "drives.joint1.gear_ratio"),
        "unknown-key": (b"drive:\n  joint1: {gear_ratio: 2}\n", "drive"),
        "unknown-joint": (b"drives:\n  elbow: {gear_ratio: 2}\n", "drives.elbow"),
        "mixed-keys": (b"1: a\nfoo: b\n", ""),
        "yaml-error": (b"drives: [\n  joint1: {gear_ratio: 2}\n", ""),
        "not-utf8": ("assumptions: [Stäubli]\n".encode("latin-1"), ""),
        "bomb": (
            b"assumptions:\n  - &a [x, x, x, x, x, x, x, x, x, x]\n"
            + b"".join(
                f"  - &{c} [{', '.join([f'*{p}'] * 10)}]\n".encode()
                for p, c in zip("abcdef", "bcdefg", strict=True)
            ),
            "",
        ),
        "deep": (b"assumptions: " + b"[" * 200 + b"]" * 200 + b"\n", ""),
        "not-mapping": (b"- drives\n", ""),
        "tool-frame": (b"tool_frame: nowhere\n", ""),
    }
    kind = rng.choice(sorted(kinds))
    content, key = kinds[kind]
    return Case(
        f"side-{kind}",
        run_args(),
        {"s.yaml": dump(SMALL), "bot.urdf": URDF.encode(), "bot.yaml": content},
        source="{tmp}/bot.",  # the robot data file (or the URDF, for its tool frame)
        key=key,
    )


# --- command line --------------------------------------------------------------------------


def bad_option(rng: random.Random) -> Case:
    small = {"s.yaml": dump(SMALL), "bot.urdf": URDF.encode()}
    dop = {"s.yaml": dump({**SMALL, "integrator": {"method": "dop853"}}), "bot.urdf": URDF.encode()}
    longer = {"s.yaml": dump({**SMALL, "duration": 0.5}), "bot.urdf": URDF.encode()}
    options: list[tuple[list[str], dict[str, bytes], int, str, str]] = [
        (["--dt", "-1"], small, 1, "command line", "--dt"),
        (["--dt", rng.choice(["nan", "inf", "1e999"])], small, 1, "command line", "--dt"),
        (["--dt", rng.choice(["1e-300", "1e-12", "5e-324"])], small, 1, "command line", "--dt"),
        (["--dt", "1"], small, 1, "command line", "--dt"),
        (
            ["--rtol", rng.choice(["0", "-1", "nan", "5", "1e-30"])],
            dop,
            1,
            "command line",
            "--rtol",
        ),
        (
            ["--atol", rng.choice(["0", "inf", "nan", "2", "1e-300"])],
            dop,
            1,
            "command line",
            "--atol",
        ),
        (
            ["--max-steps", rng.choice(["0", "-3", "10000000000"])],
            small,
            1,
            "command line",
            "--max-steps",
        ),
        (["--integrator", "rk4", "--rtol", "1e-6"], small, 1, "command line", "--rtol"),
        (["--integrator", "dop853", "--dt", "1e-3"], small, 1, "command line", "--dt"),
        (
            ["--max-steps", str(rng.randint(1, 4)), "--integrator", "dop853"],
            longer,
            1,
            "{tmp}/s.yaml",
            "integrator.max_steps",
        ),
        (["--transition", "magic"], small, 2, "", ""),
        (["--compare", "nope"], small, 2, "", ""),
        (["--bogus"], small, 2, "", ""),
        (["--dt", "abc"], small, 2, "", ""),
        (["--max-steps", "1.5"], small, 2, "", ""),
        (["--quiet", "--json"], small, 2, "", ""),
    ]
    extra, files, status, source, key = rng.choice(options)
    return Case(f"option-{'-'.join(extra)[:30]}", run_args(*extra), files, status, source, key)


def bad_command(rng: random.Random) -> Case:
    small = {"s.yaml": dump(SMALL), "bot.urdf": URDF.encode(), "afile": b"x"}
    commands: list[tuple[list[str], int, str, str]] = [
        (["run", "{tmp}/s.yaml", "--out", "{tmp}/afile/out"], 1, "command line", "--out"),
        (["run", "{tmp}/s.yaml", "--out", "{tmp}/afile/a/b"], 1, "command line", "--out"),
        (["run", "{tmp}/s.yaml", "--out", "{tmp}/afile"], 1, "command line", "--out"),
        (["run", "{tmp}/s.yaml", "--out", "/proc/vtm-pin-test/out"], 1, "command line", "--out"),
        (["run", "{tmp}/missing.yaml", "--out", "{tmp}/out"], 1, "{tmp}/missing.yaml", ""),
        (["run", "{tmp}", "--out", "{tmp}/out"], 1, "{tmp}", ""),
        (["run", "{tmp}/" + "x" * 300 + ".yaml", "--out", "{tmp}/out"], 1, "{tmp}/", ""),
        (["list", "scenarios", "--dir", "{tmp}/nowhere"], 1, "{tmp}/nowhere", ""),
        (["list", "bogus"], 2, "", ""),
        ([], 2, "", ""),
        (["run"], 2, "", ""),
        (["frobnicate"], 2, "", ""),
    ]
    args, status, source, key = rng.choice(commands)
    return Case(f"command-{'-'.join(args)[:40]}", args, small, status, source, key)


# --- found while simulating (tiny durations) -----------------------------------------------


def found_in_run(rng: random.Random) -> Case:
    kind = rng.choice(["dock", "loop", "max-steps"])
    if kind == "dock":
        doc = yaml.safe_load(yaml.safe_dump(BASES["rx160l_dock_point"]))
        offset = [rng.uniform(-1.0, 1.0) for _ in range(3)]
        doc.update(
            duration=0.02,
            events=[
                {
                    "t": 0.01,
                    "activate": [
                        {
                            "name": "dock",
                            "type": "dock",
                            "frame_a": "tool0",
                            "target": {"xyz": offset},
                        }
                    ],
                }
            ],
        )
        return scenario_case("run-dock-off-target", doc, "events[0].activate[0].target")
    if kind == "loop":
        doc = yaml.safe_load(yaml.safe_dump(BASES["fivebar_lock"]))
        q = [x + rng.uniform(0.1, 0.5) for x in doc["initial"]["q"]]
        loop = doc.pop("constraints")[0]
        doc.update(duration=0.02, initial={"q": q}, events=[{"t": 0.01, "activate": [loop]}])
        return scenario_case("run-loop-apart", doc, "events[0].activate[0]")
    doc = {
        **SMALL,
        "duration": 0.5,
        "integrator": {"method": "dop853", "max_steps": rng.randint(1, 5)},
    }
    return scenario_case(
        "run-dop853-max-steps", doc, "integrator.max_steps", **{"bot.urdf": URDF.encode()}
    )


#: (generator, inputs per unit of scale): more than 500 inputs at scale 1.
GENERATORS: list[tuple[Callable[[random.Random], Case], int]] = [
    (bad_number, 120),
    (bad_string_type, 40),
    (bad_name, 35),
    (unknown_keys, 50),
    (deep_nesting, 20),
    (alias_bomb, 25),
    (not_utf8, 40),
    (truncated, 30),
    (semantic, 40),
    (bad_urdf, 40),
    (bad_side_file, 40),
    (bad_option, 40),
    (bad_command, 25),
    (found_in_run, 12),
]


def generate(seed: int, scale: int = 1) -> list[Case]:
    """The bad inputs of ``seed``, in a fixed order."""
    rng = random.Random(seed)
    cases = [make(rng) for make, count in GENERATORS for _ in range(count * scale)]
    return [replace(case, name=f"{i:04d}-{case.name}") for i, case in enumerate(cases)]


CASES = generate(SEED)


def snapshot(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def check(case: Case, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Run one bad input through main() and check its single line and the untouched folder."""
    tmp = str(tmp_path)
    for name, content in case.files.items():
        (tmp_path / name).write_bytes(content)
    before = snapshot(tmp_path)
    status = main([arg.replace("{tmp}", tmp) for arg in case.args])
    captured = capsys.readouterr()
    err = captured.err
    assert status == case.status, err
    assert err.endswith("\n") and err.count("\n") == 1, err
    assert "Traceback" not in err and "internal error" not in err, err
    assert captured.out == ""
    if case.status == 1:
        assert err.startswith("vtm-pin: error: "), err
        assert case.source.replace("{tmp}", tmp) in err, err
        if case.key:  # the CLI prints one line: runs of white space fold to one space
            assert " ".join(f"'{case.key}'".split()) in err, err
    else:
        assert ": error: " in err and "(see --help)" in err, err
    assert len(err) < 2200  # values are quoted as short excerpts
    assert snapshot(tmp_path) == before  # nothing written, no staging folder left


def test_the_generator_covers_every_class_with_500_inputs():
    kinds = {case.name.split("-")[1] for case in CASES}
    assert len(CASES) >= 500
    assert kinds >= {
        "number", "string", "name", "keys", "deep", "bomb", "encoding", "truncated",
        "semantic", "urdf", "side", "option", "command", "run",
    }  # fmt: skip


@pytest.mark.parametrize("case", CASES, ids=[case.name for case in CASES])
def test_bad_input_gives_one_line_and_writes_nothing(case, tmp_path, capsys):
    check(case, tmp_path, capsys)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_more_bad_input(seed, tmp_path_factory, capsys):
    """Five times as many inputs from other seeds (run with -m slow)."""
    for case in generate(seed, scale=5):
        check(case, tmp_path_factory.mktemp("case"), capsys)

"""Where a study case's time goes, by sampling: py-spy over one worker's batch of cases.

Issue 27's targets are multiples of Pinocchio's floor; this script says which part of a case
stands between it and them. It measures the mean core time of a case without a profiler
(:func:`study_floor.case_times`, one worker's way, warmed) and the floor
(:func:`study_floor.pinocchio_work`), then runs the same cases again in a child process under
``py-spy record --format raw`` (the ``profile`` extra) and shares the case time out by the
samples' stacks. Each sample goes to the first of :data:`PARTS` whose frames it holds, so the
shares add up to 100 %; the hybrid loop is split further by what resumed it
(:data:`RESUMED_BY`) and the build by its steps (:data:`BUILD_STEPS`).

Sampling is one run, one process: the shares are robust to the machine's noise, which moves
both sides of a ratio alike; the milliseconds are the unsampled mean times the share. A
sampling profiler sees Python frames only: the compiled kernels' time is counted in the frame
that called them (``dynamics``). For each part it prints what a case would cost, in multiples
of the floor, were that part's time gone: what removing it could at most buy.

    OMP_NUM_THREADS=1 python benchmarks/study_profile.py [--study S] [--cases 1250] \
        [--repeat 3] [--rate 500] [--out benchmarks/out]
"""

from __future__ import annotations

import argparse
import collections
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

#: Issue 27's target: a case's core time at most this many times the floor [-].
TARGET = 5.0
#: The frame every measured sample is under (the child's measured batch).
MEASURED = "_measured"
#: The child's line that gives its measured batches' time [s].
SAMPLED = "sampled seconds: "
#: Sampling that slows the cases by more than this factor skews the shares (py-spy at 1,000
#: samples a second tripled a batch's time here and put half of it in the build) [-].
MAX_SLOWDOWN = 1.5
#: Frames of a sample that is not the cases' own work: imports, a kernel's first load.
NOT_MEASURED = ("_find_and_load", "_compiled")
#: A plain stop's records, made for its hybrid loop (which the engine left): by their frame.
PLAIN = {
    "PlainStop.__init__": "a plain stop's first interval and engagement recorded",
    "PlainStop.result": "a plain stop's rests and end recorded",
}
#: A case's parts, in the order a sample is attributed: the first whose frames it holds.
#: A sample under the measured batch holding none of them is ``other``.
PARTS: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    ("report", "the case's figures, flags and record", ("_complete_many",)),
    (
        "build",
        "the case's scenario, Annex-B pose and bound variants",
        ("_case_raw", "build_scenario", "_Poses.solve", "bound_variants"),
    ),
    ("scalar", "runs the batched engine left to the scalar engine", ("_simulate_one",)),
    (
        "hybrid loop",
        "the case's own Python: brakes, locks, the next phase; a plain stop's records",
        ("_Run.advance", *PLAIN),
    ),
    (
        "dynamics",
        "accelerations of all lanes (compiled kernel inside)",
        ("_Dynamics.accelerations",),
    ),
    (
        "lanes",
        "per-lane Python of the batched engine: load, grids, samples, rests",
        (
            "BatchEngine._load",
            "BatchEngine._load_brakes",
            "_Run.sample",
            "BatchEngine._samples",
            "_grid_times",
            "_start_grid",
            "BatchEngine._own_margins",
            "BatchEngine._finish",
            "BatchEngine._settle_rests",
            "BatchEngine._engage",
        ),
    ),
    (
        "dense output",
        "dense output and event location across lanes",
        ("BatchEngine._dense_samples",),
    ),
    ("stepping", "the stages and error control across lanes", ("BatchEngine.run",)),
)
#: What resumed a case's hybrid loop: the frame that called ``BatchEngine.advance``.
RESUMED_BY = {
    "_run_batch": "started",
    "BatchEngine._start": "a lane's interval ended",
    "BatchEngine._hand": "an event's interval handed",
    "BatchEngine._sync": "rests handed",
    "BatchEngine._fail": "a lane failed",
}
#: The build's steps, by the first of these frames a build sample holds.
BUILD_STEPS = {
    "_case_raw": "the case's scenario document",
    "_Poses.solve": "Annex-B poses (batched Newton)",
    "bound_variants": "the bounds' variant runs",
    "build_scenario": "the scenario and model",
}


@dataclass(frozen=True)
class Profile:
    """Samples of a measured batch, shared out by part.

    Attributes:
        total: Samples under the measured batch, imports and first loads left out [-].
        parts: Samples per part of :data:`PARTS`, and ``other`` [-].
        resumed: Hybrid-loop samples per :data:`RESUMED_BY` label (``other`` if not listed).
        build: Build samples per :data:`BUILD_STEPS` label (``other`` if none).
    """

    total: int
    parts: dict[str, int]
    resumed: dict[str, int]
    build: dict[str, int]


def _names(stack: str) -> list[str]:
    """A raw stack's function names, outermost first (``name (file:line)`` frames)."""
    return [frame.rpartition(" (")[0] or frame for frame in stack.split(";")]


def _part(names: Sequence[str]) -> str:
    """The first part of :data:`PARTS` whose frames ``names`` holds, else ``other``."""
    held = set(names)
    return next((part for part, _, frames in PARTS if held.intersection(frames)), "other")


def _resumed_by(names: Sequence[str]) -> str:
    """What resumed a hybrid-loop sample: the caller of its ``BatchEngine.advance``.

    A plain stop's records (:data:`PLAIN`) are their own label.
    """
    plain = next((PLAIN[name] for name in names if name in PLAIN), None)
    if plain is not None:
        return plain
    i = names.index("BatchEngine.advance") if "BatchEngine.advance" in names else 0
    return RESUMED_BY.get(names[i - 1], "other") if i > 0 else "other"


def _build_step(names: Sequence[str]) -> str:
    """The build step of a build sample: its first frame in :data:`BUILD_STEPS`."""
    return next((BUILD_STEPS[n] for n in names if n in BUILD_STEPS), "other")


def attribute(lines: Iterable[str]) -> Profile:
    """Share out py-spy's raw samples (``stack count`` lines) by part.

    Only stacks under :data:`MEASURED` count, less those in :data:`NOT_MEASURED`.
    """
    parts: collections.Counter[str] = collections.Counter()
    resumed: collections.Counter[str] = collections.Counter()
    build: collections.Counter[str] = collections.Counter()
    for line in lines:
        stack, _, count = line.rstrip("\n").rpartition(" ")
        names = _names(stack)
        if not count.isdigit() or MEASURED not in names or set(names) & set(NOT_MEASURED):
            continue
        part = _part(names)
        parts[part] += int(count)
        if part == "hybrid loop":
            resumed[_resumed_by(names)] += int(count)
        elif part == "build":
            build[_build_step(names)] += int(count)
    return Profile(sum(parts.values()), dict(parts), dict(resumed), dict(build))


def _measured(tasks: list, repeat: int) -> float:
    """The sampled work: the cases, ``repeat`` times (the frame :data:`MEASURED`); its time [s]."""
    from vtm_pin.study.runner import run_cases

    start = time.perf_counter()
    for _ in range(repeat):
        run_cases(tasks)
    return time.perf_counter() - start


def _child(args: argparse.Namespace) -> None:
    """The sampled process: warm as a worker does, then the measured batches."""
    from study_floor import study_tasks

    from vtm_pin.study.executors import tune_collector
    from vtm_pin.study.runner import run_cases

    _, tasks = study_tasks(args.study, args.cases)
    tune_collector()
    run_cases(tasks[:50])
    print(f"{SAMPLED}{_measured(tasks, args.repeat)!r}")


def _sample(args: argparse.Namespace, spy: str) -> tuple[Profile, float]:
    """Run :func:`_child` under py-spy; its samples shared out, and its cases' time [s]."""
    with tempfile.TemporaryDirectory() as folder:
        raw = Path(folder) / "samples.raw"
        child = [sys.executable, __file__, "--child", "--study", args.study]
        child += ["--repeat", str(args.repeat), "--cases", str(args.cases)]
        command = [spy, "record", "--rate", str(args.rate), "--format", "raw", "--output", str(raw)]
        done = subprocess.run([*command, "--", *child], capture_output=True, text=True)
        if done.returncode != 0:
            last = (done.stderr.strip().splitlines() or ["no message"])[-1]
            sys.exit(f"study_profile.py: py-spy or the sampled cases failed: {last}")
        seconds = next(
            float(line.removeprefix(SAMPLED))
            for line in done.stdout.splitlines()
            if line.startswith(SAMPLED)
        )
        with raw.open() as lines:
            return attribute(lines), seconds


def _rows(profile: Profile, case_ms: float, floor_ms: float) -> list[tuple[str, float, str]]:
    """Table rows: label, share [-], and what is left without it [x floor] (parts only)."""
    rows: list[tuple[str, float, str]] = []
    described = {part: text for part, text, _ in PARTS} | {"other": "the rest (grouping, setup)"}
    for part, text in described.items():
        share = profile.parts.get(part, 0) / profile.total
        rows.append((f"{part}: {text}", share, f"{(1 - share) * case_ms / floor_ms:.1f}"))
        split = {"hybrid loop": profile.resumed, "build": profile.build}.get(part, {})
        for label, n in sorted(split.items(), key=lambda item: -item[1]):
            rows.append((f"    {label}", n / profile.total, ""))
    return rows


def _plot(
    rows: list[tuple[str, float, str]], case_ms: float, cut: float, title: str, path: Path
) -> None:
    """A bar per part: its ms a case (the unsampled mean times its share); ``cut`` [ms] marked."""
    from matplotlib.figure import Figure

    parts = [(label.split(":")[0], share * case_ms) for label, share, _ in rows if ":" in label]
    figure = Figure(figsize=(7.5, 3.6), layout="constrained")
    axes = figure.add_subplot()
    axes.barh([p for p, _ in parts][::-1], [ms for _, ms in parts][::-1], color="tab:blue")
    if cut > 0.0:  # already within the target: nothing to mark
        label = f"what must go for {TARGET:g}x the floor"
        axes.axvline(cut, color="tab:red", linestyle="--", label=label)
        axes.legend(loc="lower right", fontsize=8)
    axes.set_xlabel("time a case [ms]")
    axes.set_title(title, fontsize=9)
    figure.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study", default="ur10_envelope", help="study file or shipped name")
    parser.add_argument(
        "--cases", type=int, default=1250, help="cases a batch [-] (as study_floor)"
    )
    parser.add_argument("--repeat", type=int, default=3, help="sampled batches [-]")
    parser.add_argument("--rate", type=int, default=500, help="samples a second [1/s]")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "out")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        return _child(args)
    spy = shutil.which("py-spy") or shutil.which("py-spy", path=str(Path(sys.executable).parent))
    if spy is None:
        sys.exit("study_profile.py: py-spy is not installed; allowed: pip install -e '.[profile]'")
    from study_floor import case_times, floor_ms, pinocchio_work, study_tasks

    from vtm_pin.exceptions import VtmError

    try:
        name, tasks = study_tasks(args.study, args.cases)
    except VtmError as exc:
        sys.exit(f"study_profile.py: {exc}")
    case_ms = sum(case_times(tasks).values())
    states, _, size, model, _ = pinocchio_work(tasks)
    floor = floor_ms(model, size, states)
    profile, seconds = _sample(args, spy)
    slowdown = seconds / (1e-3 * case_ms * len(tasks) * args.repeat)
    rows = _rows(profile, case_ms, floor)
    print(
        f"study {name}: {len(tasks)} cases, x{args.repeat} sampled at {args.rate}/s; "
        f"{profile.total} samples; OMP_NUM_THREADS=1"
    )
    print(
        f"a case, unsampled: {case_ms:.2f} ms = {case_ms / floor:.1f}x the floor "
        f"({floor:.2f} ms, {states:.0f} states)"
    )
    print(f"sampling slowed the cases {slowdown:.2f}x (unsampled mean against the sampled batches)")
    if slowdown > MAX_SLOWDOWN:
        print(f"WARNING: over {MAX_SLOWDOWN}x: the shares are skewed; lower --rate")
    print(f"{'part':<78} {'share':>6} {'[ms]':>6} {'x floor without':>16}")
    for label, share, left in rows:
        print(f"{label:<78} {100 * share:>5.1f}% {share * case_ms:>6.3f} {left:>16}")
    cut = case_ms - TARGET * floor
    print(
        f"to reach {TARGET:g}x the floor, {max(cut, 0.0):.3f} ms a case "
        f"({100 * max(cut, 0.0) / case_ms:.0f} %) must go"
    )
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"study_profile_{name}.png"
    title = f"{name}: {case_ms:.2f} ms a case, {case_ms / floor:.1f}x the floor (sampled shares)"
    _plot(rows, case_ms, cut, title, path)
    print(f"plot: {path}")


if __name__ == "__main__":
    main()

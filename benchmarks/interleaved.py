"""Two versions of vtm_pin against each other on a study's cases, in interleaved rounds.

This machine's speed moves by up to 2x between minutes (its cores are shared), more than most
changes gain, so one run of each version cannot tell them apart. This runs the first
``--cases`` cases of a study (one worker's batch, warmed: :func:`study_floor.case_times`)
with each version's package in a fresh process, ``--rounds`` times in ABBA order (new, old,
old, new, ...), so that a drift of the machine's speed falls on both alike, and prints each
round's core time a case (build + simulate + report) [ms] of both, their ratio, the median
ratio with its range and how many rounds are below 1, the parts' medians, and a plot.

A version is a git commit, branch or tag of this repository (its whole tree, from ``git
archive``, in a temporary folder, with its own robots, scenarios and studies; commit a change
to measure it) or a checkout's folder (whose data folders are those of the installed package,
``pip install -e``). Each process says which package it imported; one that did not import its
version's stops the script. The kernels a version compiles (``fast`` extra) are compiled in
its first process's warm-up, not in a measured batch.

    OMP_NUM_THREADS=1 python benchmarks/interleaved.py NEW OLD [--study S] [--cases 1250] \
        [--rounds 6] [--out benchmarks/out]
"""

from __future__ import annotations

import argparse
import io
import json
import statistics
import subprocess
import sys
import tarfile
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

#: The two versions, as the rounds name them.
NEW, OLD = "new", "old"
#: The parts of a case's core time (:data:`study_floor.PARTS`).
PARTS = ("build", "simulate", "report")
#: The child's line that gives its figures (JSON).
FIGURES = "figures: "
ROOT = Path(__file__).resolve().parents[1]


def order(rounds: int) -> list[str]:
    """The versions in the order they run: ABBA (new, old, old, new, new, old, ...)."""
    pairs = [(NEW, OLD) if r % 2 == 0 else (OLD, NEW) for r in range(rounds)]
    return [version for pair in pairs for version in pair]


@dataclass(frozen=True)
class Comparison:
    """Each round's case time of both versions [ms] and what they say together.

    Attributes:
        new: The new version's core time a case per round [ms].
        old: The old one's, in the same rounds [ms].
        ratios: new / old per round [-].
        median: Their median [-]: below 1, the new version is faster.
        parts: Per version, each part's median over the rounds [ms].
    """

    new: tuple[float, ...]
    old: tuple[float, ...]
    ratios: tuple[float, ...]
    median: float
    parts: Mapping[str, Mapping[str, float]]


def compare(figures: Sequence[tuple[str, Mapping[str, float]]]) -> Comparison:
    """The rounds' figures, ``(version, {part: ms})`` in the order they ran, paired by round."""
    by_version: dict[str, list[Mapping[str, float]]] = {NEW: [], OLD: []}
    for version, parts in figures:
        by_version[version].append(parts)
    if not by_version[NEW] or len(by_version[NEW]) != len(by_version[OLD]):
        raise ValueError("every round needs one figure of each version")
    new, old = (tuple(sum(p[k] for k in PARTS) for p in by_version[v]) for v in (NEW, OLD))
    ratios = tuple(a / b for a, b in zip(new, old, strict=True))
    parts = {
        version: {k: statistics.median(p[k] for p in rows) for k in PARTS}
        for version, rows in by_version.items()
    }
    return Comparison(new, old, ratios, statistics.median(ratios), parts)


def extract(ref: str, into: Path) -> None:
    """This repository's tree at git ``ref`` in ``into``, its data folders inside its package.

    The package ships ``robots/``, ``scenarios/`` and the like as its subpackages
    (``package-dir`` in its ``pyproject.toml``); links make them so in the extracted tree.
    """
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref], capture_output=True)
    if archive.returncode != 0:
        last = (archive.stderr.decode().strip().splitlines() or ["no message"])[-1]
        sys.exit(f"interleaved.py: '{ref}' is neither a checkout nor a commit here: {last}")
    with tarfile.open(fileobj=io.BytesIO(archive.stdout)) as tar:
        tar.extractall(into, filter="data")
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        sys.exit("interleaved.py: needs Python 3.11 or later (tomllib reads a tree's pyproject)")
    with (into / "pyproject.toml").open("rb") as file:
        mapped = tomllib.load(file).get("tool", {}).get("setuptools", {}).get("package-dir", {})
    for package, folder in mapped.items():
        link = into.joinpath(*package.split("."))
        if not link.exists():
            link.symlink_to(into / folder, target_is_directory=True)


def tree(version: str, folder: Path) -> Path:
    """The folder of ``version``: a checkout as it is, or a commit extracted into ``folder``."""
    given = Path(version)
    if (given / "vtm_pin" / "__init__.py").is_file():
        return given.resolve()
    folder.mkdir()
    extract(version, folder)
    return folder.resolve()


def _child(args: argparse.Namespace) -> None:
    """Time the cases with the package of ``args.tree`` (first on the path)."""
    sys.path[:0] = [str(args.tree), str(Path(__file__).parent)]
    from study_floor import case_times, study_tasks

    import vtm_pin

    _, tasks = study_tasks(args.study, args.cases)
    figures = dict(case_times(tasks), package=str(Path(vtm_pin.__file__).parent))
    print(FIGURES + json.dumps(figures))


def _measure(folder: Path, args: argparse.Namespace) -> dict[str, float]:
    """One round of the package in ``folder``, in a child process; its parts [ms]."""
    command = [sys.executable, __file__, "--child", "--tree", str(folder)]
    command += ["--study", args.study, "--cases", str(args.cases)]
    done = subprocess.run(command, capture_output=True, text=True)
    lines = [x for x in done.stdout.splitlines() if x.startswith(FIGURES)]
    if done.returncode != 0 or not lines:
        last = (done.stderr.strip().splitlines() or ["no message"])[-1]
        sys.exit(f"interleaved.py: the cases failed with the package in {folder}: {last}")
    figures = json.loads(lines[-1].removeprefix(FIGURES))
    package = Path(figures.pop("package"))
    if package != folder / "vtm_pin":
        sys.exit(f"interleaved.py: the process for {folder} imported the package in {package}")
    return figures


def _plot(result: Comparison, title: str, path: Path) -> None:
    """Both versions' case time per round [ms]."""
    from matplotlib.figure import Figure

    figure = Figure(figsize=(6.5, 3.4), layout="constrained")
    axes = figure.add_subplot()
    rounds = range(1, len(result.new) + 1)
    axes.plot(rounds, result.new, "s-", label=NEW)
    axes.plot(rounds, result.old, "o-", label=OLD)
    axes.set_xlabel("round")
    axes.set_ylabel("core time a case [ms]")
    axes.set_title(title, fontsize=9)
    axes.legend(fontsize=8)
    figure.savefig(path, dpi=120)


def _print(result: Comparison, versions: tuple[str, str], study: str, cases: int) -> None:
    print(f"{study}: {cases} cases a process; {NEW} = {versions[0]}, {OLD} = {versions[1]}")
    print(f"{'round':>5} {NEW + ' [ms]':>10} {OLD + ' [ms]':>10} {'new/old':>8}")
    for r, (a, b, ratio) in enumerate(zip(result.new, result.old, result.ratios, strict=True)):
        print(f"{r + 1:>5} {a:>10.3f} {b:>10.3f} {ratio:>8.3f}")
    low, high, below = min(result.ratios), max(result.ratios), sum(r < 1 for r in result.ratios)
    print(
        f"new / old: median {result.median:.3f} (from {low:.3f} to {high:.3f}; below 1 in "
        f"{below} of {len(result.ratios)} rounds)"
    )
    for version, parts in result.parts.items():
        shown = ", ".join(f"{k} {ms:.3f}" for k, ms in parts.items())
        print(f"{version}: medians over the rounds [ms]: {shown}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("new", nargs="?", help="commit, branch, tag or checkout folder")
    parser.add_argument("old", nargs="?", help="the version it is compared with")
    parser.add_argument("--study", default="ur10_envelope", help="study file or shipped name")
    parser.add_argument("--cases", type=int, default=1250, help="cases a process runs [-]")
    parser.add_argument(  # --pairs: its name before rounds ran in ABBA order
        "--rounds", "--pairs", type=int, default=6, help="rounds of both versions [-]"
    )
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "out")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--tree", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        _child(args)
        return
    if args.old is None or args.rounds < 1 or args.cases < 1:
        sys.exit("interleaved.py: give NEW and OLD, and --rounds and --cases of at least 1")
    with tempfile.TemporaryDirectory() as folder:
        versions = {NEW: args.new, OLD: args.old}
        trees = {v: tree(versions[v], Path(folder) / v) for v in (NEW, OLD)}
        figures = [(v, _measure(trees[v], args)) for v in order(args.rounds)]
    result = compare(figures)
    _print(result, (args.new, args.old), args.study, args.cases)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"interleaved_{Path(args.study).stem}.png"
    _plot(result, f"{args.study}: {args.new} ({NEW}) against {args.old} ({OLD})", path)
    print(f"plot: {path}")


if __name__ == "__main__":
    main()

"""A change's effect on a study case's time, measured against the noise: two trees alternated.

This machine's speed moves by up to 2x between minutes (its cores are shared), so two figures
measured minutes apart cannot show a change of a few per cent. This script runs the same
``--cases`` cases of a study (one worker's batch, warmed: :func:`study_floor.case_times`) with
the package of two commits of this repository, ``--against`` (old) and ``--ref`` (new, HEAD by
default; commit a change to measure it): each commit's whole tree, from ``git archive``, in a
temporary folder with its own robots, scenarios and studies. Each round runs both, each in a
fresh child process, in ABBA order (old, new, new, old, ...), so that a drift of the
machine's speed falls on both alike. It prints each round's mean core time a case (build +
simulate + report) [ms] for both and their ratio, the median ratio with its range, the parts'
medians, and a plot. A child says which package it imported; one that did not import its
tree's stops the script.

    OMP_NUM_THREADS=1 python benchmarks/ab_cases.py --against OLD [--ref HEAD] [--study S] \
        [--cases 1250] [--rounds 6] [--out benchmarks/out]
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

#: The two trees, as the rounds name them.
OLD, NEW = "old", "new"
#: The parts of a case's core time (:data:`study_floor.PARTS`).
PARTS = ("build", "simulate", "report")
#: The child's line that gives its figures (JSON).
FIGURES = "figures: "
ROOT = Path(__file__).resolve().parents[1]


def order(rounds: int) -> list[str]:
    """The trees in the order they run: ABBA (old, new, new, old, old, new, ...)."""
    pairs = [(OLD, NEW) if r % 2 == 0 else (NEW, OLD) for r in range(rounds)]
    return [tree for pair in pairs for tree in pair]


@dataclass(frozen=True)
class Comparison:
    """Each round's case time of both trees [ms] and what they say together.

    Attributes:
        old: The ``--against`` tree's core time a case per round [ms].
        new: The ``--ref`` tree's, in the same rounds [ms].
        ratios: new / old per round [-].
        median: Their median [-]: below 1, this tree is faster.
        parts: Per tree, each part's median over the rounds [ms].
    """

    old: tuple[float, ...]
    new: tuple[float, ...]
    ratios: tuple[float, ...]
    median: float
    parts: Mapping[str, Mapping[str, float]]


def compare(figures: Sequence[tuple[str, Mapping[str, float]]]) -> Comparison:
    """The rounds' figures, ``(tree, {part: ms})`` in the order they ran, paired by round."""
    by_tree: dict[str, list[Mapping[str, float]]] = {OLD: [], NEW: []}
    for tree, parts in figures:
        by_tree[tree].append(parts)
    if not by_tree[OLD] or len(by_tree[OLD]) != len(by_tree[NEW]):
        raise ValueError("every round needs one figure of each tree")
    old = tuple(sum(p[k] for k in PARTS) for p in by_tree[OLD])
    new = tuple(sum(p[k] for k in PARTS) for p in by_tree[NEW])
    ratios = tuple(b / a for a, b in zip(old, new, strict=True))
    parts = {
        tree: {k: statistics.median(p[k] for p in rows) for k in PARTS}
        for tree, rows in by_tree.items()
    }
    return Comparison(old, new, ratios, statistics.median(ratios), parts)


def extract(ref: str, into: Path) -> None:
    """This repository's tree at git ``ref`` in ``into``, its data folders inside its package.

    The package ships ``robots/``, ``scenarios/`` and the like as its subpackages
    (``package-dir`` in its ``pyproject.toml``); links make them so in the extracted tree.
    """
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref], capture_output=True)
    if archive.returncode != 0:
        last = (archive.stderr.decode().strip().splitlines() or ["no message"])[-1]
        sys.exit(f"ab_cases.py: '{ref}' is not a commit of this repository: {last}")
    with tarfile.open(fileobj=io.BytesIO(archive.stdout)) as tar:
        tar.extractall(into, filter="data")
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        sys.exit("ab_cases.py: needs Python 3.11 or later (tomllib reads the tree's pyproject)")
    with (into / "pyproject.toml").open("rb") as file:
        mapped = tomllib.load(file).get("tool", {}).get("setuptools", {}).get("package-dir", {})
    for package, folder in mapped.items():
        link = into.joinpath(*package.split("."))
        if not link.exists():
            link.symlink_to(into / folder, target_is_directory=True)


def _child(args: argparse.Namespace) -> None:
    """Time the cases with the package of ``args.tree`` (first on the path)."""
    sys.path[:0] = [str(args.tree), str(Path(__file__).parent)]
    from study_floor import case_times, study_tasks

    import vtm_pin

    _, tasks = study_tasks(args.study, args.cases)
    figures = dict(case_times(tasks), package=str(Path(vtm_pin.__file__).parent))
    print(FIGURES + json.dumps(figures))


def _measure(tree: Path, args: argparse.Namespace) -> dict[str, float]:
    """One round of the package in ``tree``, in a child process; its parts [ms]."""
    command = [sys.executable, __file__, "--child", "--tree", str(tree)]
    command += ["--study", args.study, "--cases", str(args.cases)]
    done = subprocess.run(command, capture_output=True, text=True)
    lines = [x for x in done.stdout.splitlines() if x.startswith(FIGURES)]
    if done.returncode != 0 or not lines:
        last = (done.stderr.strip().splitlines() or ["no message"])[-1]
        sys.exit(f"ab_cases.py: the cases failed with the tree of {tree.name}: {last}")
    figures = json.loads(lines[-1].removeprefix(FIGURES))
    package = Path(figures.pop("package"))
    if package != tree / "vtm_pin":
        sys.exit(f"ab_cases.py: the child for {tree} imported the package in {package}")
    return figures


def _plot(result: Comparison, title: str, path: Path) -> None:
    """Both trees' case time per round [ms]."""
    from matplotlib.figure import Figure

    figure = Figure(figsize=(6.5, 3.4), layout="constrained")
    axes = figure.add_subplot()
    rounds = range(1, len(result.old) + 1)
    axes.plot(rounds, result.old, "o-", label=f"{OLD} (--against)")
    axes.plot(rounds, result.new, "s-", label=f"{NEW} (--ref)")
    axes.set_xlabel("round")
    axes.set_ylabel("core time a case [ms]")
    axes.set_title(title, fontsize=9)
    axes.legend(fontsize=8)
    figure.savefig(path, dpi=120)


def _print(result: Comparison, refs: tuple[str, str], study: str, cases: int) -> None:
    print(f"study {study}: {cases} cases a round, one child process each")
    print(f"{OLD} = {refs[0]}, {NEW} = {refs[1]}")
    print(f"{'round':>5} {OLD + ' [ms]':>10} {NEW + ' [ms]':>10} {'new/old':>8}")
    for r, (a, b, ratio) in enumerate(zip(result.old, result.new, result.ratios, strict=True)):
        print(f"{r + 1:>5} {a:>10.3f} {b:>10.3f} {ratio:>8.3f}")
    low, high = min(result.ratios), max(result.ratios)
    print(f"new / old: median {result.median:.3f} (from {low:.3f} to {high:.3f})")
    for tree, parts in result.parts.items():
        shown = ", ".join(f"{k} {ms:.3f}" for k, ms in parts.items())
        print(f"{tree}: medians over the rounds [ms]: {shown}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", help="the old commit, branch or tag")
    parser.add_argument("--ref", default="HEAD", help="the new commit, branch or tag")
    parser.add_argument("--study", default="ur10_envelope", help="study file or shipped name")
    parser.add_argument("--cases", type=int, default=1250, help="cases a round [-]")
    parser.add_argument("--rounds", type=int, default=6, help="rounds of both trees [-]")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "out")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--tree", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        _child(args)
        return
    if args.against is None or args.rounds < 1 or args.cases < 1:
        sys.exit("ab_cases.py: give --against REF, and --rounds and --cases of at least 1")
    with tempfile.TemporaryDirectory() as folder:
        trees = {OLD: Path(folder).resolve() / OLD, NEW: Path(folder).resolve() / NEW}
        for tree, ref in ((OLD, args.against), (NEW, args.ref)):
            trees[tree].mkdir()
            extract(ref, trees[tree])
        figures = [(tree, _measure(trees[tree], args)) for tree in order(args.rounds)]
    result = compare(figures)
    _print(result, (args.against, args.ref), args.study, args.cases)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"ab_cases_{Path(args.study).stem}.png"
    _plot(result, f"{args.study}: {args.against} ({OLD}) against {args.ref} ({NEW})", path)
    print(f"plot: {path}")


if __name__ == "__main__":
    main()

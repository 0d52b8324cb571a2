"""Command line: ``vtm-pin run SCENARIO``, ``study STUDY``, ``calibrate``, ``list``, ``init``."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import textwrap
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from importlib.metadata import version
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
from tqdm import tqdm

from .calibration.comparison import (
    CLASSES,
    SHORT_TOLERANCE,
    Comparison,
    compare,
    judge,
    recommend,
    shared,
    warning_line,
)
from .calibration.fit import (
    DISTANCE_SCATTER,
    FIGURES,
    TIME_SCATTER,
    LeftOut,
    calibrate,
    check_table,
    leave_one_out,
)
from .calibration.report import calibration_summary, format_calibration, write_calibration
from .calibration.table import read_stopping_table
from .exceptions import (
    InputError,
    OutputError,
    ScenarioError,
    StudyError,
    UnsupportedJoint,
    VtmError,
    VtmWarning,
    excerpt,
)
from .files.inputs import read_text, read_yaml
from .files.interrupts import EXIT_INTERRUPTED, forget_interrupt
from .numerics.integrators import INTEGRATORS
from .numerics.transitions import TRANSITIONS
from .outputs.pipeline import Progress, check_output_folder, find_scenario, run, write_outputs
from .outputs.report import format_figures, format_stopping, format_summary, integrator_settings
from .physics.robot import ROBOTS_DIR, list_example_robots, list_local_robots, load_robot
from .scene.program import PROGRAMS_DIR
from .scene.scenario import SCENARIOS_DIR, Scenario, build_integrator, list_scenarios, load_scenario
from .shipped import KINDS, init_files, shipped_names
from .study.cases import STUDIES_DIR, Study, find_study, load_study
from .study.executors import default_workers, start_fork_server
from .study.program_report import format_program, run_program
from .study.runner import format_study, run_study
from .study.store import count_stored
from .study.sweep import DEFAULT_EVERY, DEFAULT_TOLERANCE, SEARCH_FIGURES, load_program_study

#: Exit codes: success, a user error (bad scenario, robot or option value), bad usage of the
#: command line, interrupted by Ctrl-C. Nothing is written unless the code is EXIT_OK.
EXIT_OK, EXIT_ERROR, EXIT_USAGE = 0, 1, 2
#: A run shows a progress bar (on a terminal) once it has taken this long [s].
PROGRESS_DELAY = 1.0
#: Longest message printed [characters]; every message is one line.
MAX_MESSAGE = 2000

_EPILOG = """\
units: SI throughout - time s, angles rad, rates rad/s, torques N m, impulses N m s, energy J,
lengths m. Motor-side values are joint-side values times the gear ratio.

exit status:
  0    success
  1    user error: bad scenario file, unknown robot or joint, bad option value
       (one line on stderr; nothing is written)
  2    bad command-line usage
  130  interrupted (Ctrl-C); nothing is written

examples:
  vtm-pin run pendulum3r --compare naive
  vtm-pin run scenarios/rx160l_estop_cat0.yaml --integrator dop853 --rtol 1e-8 --json
  vtm-pin study ur10_annex_b --out results/ur10_annex_b --workers 2
  vtm-pin calibrate table.csv --robot ur5_cb3 --out results/ur5_cb3_calibration
  vtm-pin list scenarios
  vtm-pin init scenario ur10_annex_b
"""


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code instead of exiting (tests call this).

    Every message is one line on stderr. Warnings are printed once the command has succeeded;
    a failing command prints its error line only. NumPy's floating-point warnings are not
    printed: a state that overflows is caught and explained by the simulation's own checks.
    """
    parser = _parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse has printed its usage error, or --help / --version
        return int(exc.code) if isinstance(exc.code, int) else EXIT_USAGE
    with warnings.catch_warnings(record=True) as caught, np.errstate(all="ignore"):
        warnings.simplefilter("always", VtmWarning)
        try:
            code = int(args.func(args))
        except VtmError as exc:
            return _fail(str(exc))
        except KeyboardInterrupt:
            forget_interrupt()
            print("vtm-pin: interrupted; nothing written", file=sys.stderr)
            return EXIT_INTERRUPTED
        except Exception as exc:  # a bug: still one line, and no partial output
            if os.environ.get("VTM_PIN_DEBUG"):
                raise
            return _fail(
                f"internal error ({type(exc).__name__}: {exc}); please report it with the input "
                "(VTM_PIN_DEBUG=1 shows the traceback)"
            )
    for message in dict.fromkeys(str(w.message) for w in caught):
        print(f"vtm-pin: warning: {one_line(message)}", file=sys.stderr)
    return code


def one_line(text: str) -> str:
    """``text`` on one line (whitespace collapsed), cut to :data:`MAX_MESSAGE` characters."""
    text = " ".join(text.split())
    return text if len(text) <= MAX_MESSAGE else text[: MAX_MESSAGE - 1] + "…"


def _fail(message: str) -> int:
    print(f"vtm-pin: error: {one_line(message)}", file=sys.stderr)
    return EXIT_ERROR


class _Parser(argparse.ArgumentParser):
    """argparse's parser, with a usage error in one line like every other error."""

    def error(self, message: str) -> NoReturn:
        """Print the error in one line and exit with status 2."""
        self.exit(EXIT_USAGE, f"{self.prog}: error: {one_line(message)} (see --help)\n")


def _parser() -> argparse.ArgumentParser:
    formatter = argparse.RawDescriptionHelpFormatter
    parser = _Parser(
        prog="vtm-pin",
        description=_wrap(
            "Emergency-stop simulator: joints lock one after another, and at each lock the "
            "velocity jumps so that the free joints' momentum is conserved (A. Mueller's "
            "transition conditions, on Pinocchio)."
        ),
        epilog=_EPILOG,
        formatter_class=formatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {version('vtm_pin')}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    run = sub.add_parser(
        "run",
        help="simulate a scenario; print its summary, write results and plots",
        description=_wrap(
            "Simulate SCENARIO: a scenario file, or the name of a shipped scenario (see "
            "'vtm-pin list scenarios'). Prints a per-event table (and a stopping report if "
            "the scenario has a stop) and writes summary.json, trajectory.csv and PNG plots "
            "into --out. Everything is written to a staging folder first and moved in only "
            "when all succeeded. A progress bar appears on runs longer than a second."
        ),
        epilog=_EPILOG,
        formatter_class=formatter,
    )
    run.add_argument(
        "scenario",
        metavar="SCENARIO",
        help="scenario file, or the name of a shipped scenario (pendulum3r); a file of that "
        "name that exists wins",
    )
    run.add_argument(
        "--out",
        type=_folder,
        default=None,
        metavar="DIR",
        help="output folder (default: results/<scenario name>); files in it are replaced",
    )
    run.add_argument(
        "--transition",
        choices=sorted(TRANSITIONS),
        default=None,
        help="velocity jump at a lock, overriding the scenario's: kkt (default), projected and "
        "minimal are the paper's three equivalent momentum-consistent forms; naive zeroes the "
        "locked rates and keeps the others (Drake, Gazebo)",
    )
    run.add_argument(
        "--compare",
        choices=sorted(TRANSITIONS),
        action="append",
        default=[],
        metavar="RULE",
        help="also run with this transition rule and overlay it in the plots (repeatable), "
        "e.g. --compare naive",
    )
    run.add_argument(
        "--integrator",
        choices=sorted(INTEGRATORS),
        default=None,
        help="integrator, overriding the scenario's: rk4 or euler (fixed step --dt) or dop853 "
        "(adaptive, --rtol / --atol)",
    )
    run.add_argument("--dt", type=float, default=None, metavar="S", help="rk4/euler step [s]")
    run.add_argument(
        "--rtol", type=float, default=None, metavar="X", help="dop853 relative tolerance [-]"
    )
    run.add_argument(
        "--atol",
        type=float,
        default=None,
        metavar="X",
        help="dop853 absolute tolerance [rad for angles, rad/s for rates]",
    )
    run.add_argument(
        "--max-steps",
        type=int,
        default=None,
        metavar="N",
        help="most integrator steps (rk4/euler: of the run, refused up front; dop853: between "
        "two events), overriding the scenario's integrator.max_steps (default 1000000)",
    )
    run.add_argument(
        "--no-plots", action="store_true", help="write no PNG figures (faster, for scripts)"
    )
    _output_options(run)
    run.set_defaults(func=_run)
    _study_parser(sub, formatter)
    _program_parser(sub, formatter)
    _calibrate_parser(sub, formatter)

    listing = sub.add_parser(
        "list",
        help="list the robots, scenarios or studies that can be run, and where they live",
        description=_wrap(
            "List the shipped robots (and the example-robot-data names), the scenario "
            "files of a folder, or the shipped studies, with the folder they are in "
            "('vtm-pin init' copies one here to start from)."
        ),
        epilog=_EPILOG,
        formatter_class=formatter,
    )
    listing.add_argument("what", choices=["robots", "scenarios", "studies", "programs"])
    listing.add_argument(
        "--dir",
        type=Path,
        default=None,
        metavar="DIR",
        help="scenarios: folder to list (default: the scenarios shipped with vtm-pin)",
    )
    listing.add_argument(
        "--check",
        action="store_true",
        help="robots: also load every example-robot-data model and say which ones vtm-pin "
        "accepts (takes a minute)",
    )
    listing.add_argument("--json", action="store_true", help="print the list as JSON")
    listing.set_defaults(func=_list)
    _init_parser(sub, formatter)
    return parser


def _init_parser(sub: Any, formatter: type[argparse.HelpFormatter]) -> None:
    init = sub.add_parser(
        "init",
        help="copy a shipped scenario, study or robot here, to start from",
        description=_wrap(
            "Copy the shipped KIND named NAME (see 'vtm-pin list') into --to, to edit and run "
            "from there. The copy works where it lands: a study names its base scenario by "
            "its shipped name, a scenario's included fragments are copied beside it, a robot "
            "comes as its URDF and its data file (drives, brakes, rated payload) side by "
            "side. Existing files are never replaced: nothing is copied if one exists."
        ),
        epilog=_EPILOG,
        formatter_class=formatter,
    )
    init.add_argument("kind", metavar="KIND", help=f"one of {', '.join(KINDS)}")
    init.add_argument("name", metavar="NAME", help="a shipped name (vtm-pin list)")
    init.add_argument(
        "--to",
        type=_folder,
        default=Path(),
        metavar="DIR",
        help="folder to copy into (default: this folder; made if missing)",
    )
    init.set_defaults(func=_init)


def _init(args: argparse.Namespace) -> int:
    written = init_files(args.kind, args.name, args.to)
    print(f"wrote {', '.join(str(path) for path in written)}")
    return EXIT_OK


def _output_options(parser: argparse.ArgumentParser) -> None:
    output = parser.add_mutually_exclusive_group()
    output.add_argument(
        "--quiet", action="store_true", help="print nothing but warnings and errors"
    )
    output.add_argument(
        "--json",
        action="store_true",
        help="print summary.json to stdout instead of the tables (no progress bar)",
    )


def _study_parser(sub: Any, formatter: type[argparse.HelpFormatter]) -> None:
    study = sub.add_parser(
        "study",
        help="run a study: a base scenario over a grid or a sample of its settings",
        description=_wrap(
            "Run STUDY: a study file (a base scenario and what varies), or the name of a "
            "shipped study. Each case is a full run; a failed case is recorded with its "
            "message and the study goes on. Finished cases are stored in DIR/cases as they "
            "complete: run the same command again after an interruption and only the missing "
            "cases are computed. Writes results.parquet, results.csv, summary.json, the "
            "stopping graphs, the Annex-B table and report.html into --out."
        ),
        epilog=_EPILOG,
        formatter_class=formatter,
    )
    study.add_argument("study", metavar="STUDY", help="study file, or a shipped study's name")
    study.add_argument(
        "--out",
        type=_folder,
        default=None,
        metavar="DIR",
        help="output folder (default: results/<study name>); reused to resume",
    )
    _case_options(study)
    study.add_argument(
        "--yes",
        action="store_true",
        help=f"run a study of more than {CONFIRM_CASES} cases without asking (needed in scripts)",
    )
    _output_options(study)
    study.set_defaults(func=_study)


def _program_parser(sub: Any, formatter: type[argparse.HelpFormatter]) -> None:
    program = sub.add_parser(
        "program",
        help="stop the robot anywhere along its own program: distances, S and S_p, override",
        description=_wrap(
            "Trigger the base scenario's stop at instants along PROGRAM (a CSV or Parquet "
            "file: time [s] and one column per joint [rad], optional v_<joint> [rad/s]; or a "
            "shipped program's name): every --every seconds of program time, plus the "
            "instants of peak joint speed and peak tool speed. Each trigger is a study case "
            "that starts from the program's q and v there (v times each --override F). "
            "Writes program.csv (one row per trigger), program.png, the swept region "
            "(swept.png, swept.npz), program.html and the study's files into --out. With "
            "--within D: the largest override F in (0, 1] whose every trigger keeps --figure "
            "(with its upper bound where the scenario asks for bounds) within D metres."
        ),
        epilog=_EPILOG,
        formatter_class=formatter,
    )
    program.add_argument("program", metavar="PROGRAM", help="program file, or a shipped name")
    program.add_argument(
        "--scenario",
        required=True,
        metavar="BASE",
        help="base scenario (file or shipped name): robot, payload, brakes, stop at t = 0, "
        "safeguard, separation inputs, bounds",
    )
    program.add_argument(
        "--out",
        type=_folder,
        default=None,
        metavar="DIR",
        help="output folder (default: results/<program name>); reused to resume",
    )
    program.add_argument(
        "--every",
        type=_positive_float,
        default=DEFAULT_EVERY,
        metavar="DT",
        help=f"spacing of the triggers [s] of program time (default {DEFAULT_EVERY})",
    )
    program.add_argument(
        "--override",
        type=_positive_float,
        nargs="+",
        default=[1.0],
        metavar="F",
        help="speed overrides in (0, 1] [-] (default 1): the program's velocities times F",
    )
    program.add_argument(
        "--within",
        type=_positive_float,
        default=None,
        metavar="D",
        help="allowed distance [m]: find the largest override keeping --figure within it",
    )
    program.add_argument(
        "--figure",
        choices=tuple(SEARCH_FIGURES),
        default="ssm_distance",
        help="the figure --within bounds (default ssm_distance, S_p of ISO/TS 15066)",
    )
    program.add_argument(
        "--tolerance",
        type=_positive_float,
        default=DEFAULT_TOLERANCE,
        metavar="DF",
        help=f"bisection tolerance on F [-] (default {DEFAULT_TOLERANCE})",
    )
    _case_options(program)
    _output_options(program)
    program.set_defaults(func=_program)


def _case_options(parser: argparse.ArgumentParser) -> None:
    """--engine, and --workers or --scheduler: where the cases of a study or a program run."""
    parser.add_argument(
        "--engine",
        choices=("batched", "scalar"),
        default="batched",
        help="batched (default): each worker advances many cases together, one Pinocchio call "
        "per stage (cases it cannot take run on the scalar engine, counted in summary.json); "
        "scalar: one case at a time",
    )
    where = parser.add_mutually_exclusive_group()
    where.add_argument(
        "--workers",
        type=_positive_int,
        default=None,
        metavar="N",
        help="processes on this machine (default: all cores)",
    )
    where.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="send the cases to this Dask scheduler, e.g. tcp://host:8786 (needs the cluster "
        "extra; the workers need vtm_pin and the scenario's robot files)",
    )


@contextmanager
def _case_bar(name: str, show: bool) -> Iterator[Callable[[int, int], None]]:
    """A progress bar of cases on stderr (shown on a terminal only); it goes when the block ends."""
    bar = tqdm(desc=name, unit="case", file=sys.stderr, disable=not show, smoothing=0.1)

    def progress(done: int, total: int) -> None:
        bar.total = total
        bar.update(done - bar.n)

    try:
        yield progress
    finally:
        bar.close()


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{excerpt(text)}' is not a number") from None
    if not (math.isfinite(value) and value > 0.0):
        raise argparse.ArgumentTypeError(f"{value} must be a finite number > 0")
    return value


def _program(args: argparse.Namespace) -> int:
    study = load_program_study(
        args.program, args.scenario, every=args.every, overrides=args.override
    )
    out = args.out if args.out is not None else Path("results") / study.name
    try:
        check_output_folder(out)
    except OutputError as exc:
        raise StudyError("command line", "--out", exc.problem) from exc
    show = not (args.quiet or args.json) and sys.stderr.isatty()
    begin = time.perf_counter()
    try:
        with _case_bar(study.name, show) as progress:
            output = run_program(
                study,
                out,
                workers=args.workers,
                scheduler=args.scheduler,
                progress=progress,
                engine=args.engine,
                within=args.within,
                figure=args.figure,
                tolerance=args.tolerance,
            )
    except KeyboardInterrupt:
        forget_interrupt()
        print(
            f"vtm-pin: interrupted; the finished cases are stored in {out}; run the same "
            "command again to continue",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    if args.json:
        print(json.dumps(output.summary, indent=2, allow_nan=False))
    elif not args.quiet:
        print(format_program(output, time.perf_counter() - begin))
        print(f"wrote {out}/: {', '.join(output.files)}")
    return EXIT_OK


def _calibrate_parser(sub: Any, formatter: type[argparse.HelpFormatter]) -> None:
    calibrate = sub.add_parser(
        "calibrate",
        help="fit hidden brake and drive figures to a maker's published stopping table",
        description=_wrap(
            "Turn every row of TABLE (the stopping-table CSV format of the README) into the "
            "Annex-B scenario it describes, and fit brake and drive figures with least squares "
            "on the published distances and times. By default every model class (--classes) "
            "is fitted and compared (chi2 per degree of freedom, AIC, BIC, bias, leave-one-out "
            "with shared figures) and the simplest class that fits is written; --fit fits one "
            "set of figures instead. Writes calibration.json (figures with 1-sigma "
            "uncertainties, every row published vs simulated, the comparison), calibrated.yaml "
            "(a drives-and-brakes fragment a scenario can include, with the figures' "
            "covariance for bounds) and calibration.png into --out."
        ),
        epilog=_EPILOG,
        formatter_class=formatter,
    )
    calibrate.add_argument("table", metavar="TABLE", type=Path, help="stopping table (CSV)")
    calibrate.add_argument(
        "--robot", required=True, help="robot: a robots/ name, URDF path or example-robot-data name"
    )
    calibrate.add_argument(
        "--fit",
        default=None,
        metavar="FIGURES",
        help=f"fit these comma-separated figures instead of comparing classes: "
        f"{', '.join(FIGURES)}",
    )
    calibrate.add_argument(
        "--classes",
        default=",".join(CLASSES),
        metavar="NAMES",
        help=f"model classes to compare, simplest first (default {','.join(CLASSES)})",
    )
    calibrate.add_argument(
        "--short-tolerance",
        type=float,
        default=SHORT_TOLERANCE,
        metavar="X",
        help="a class fits only if no published time or distance is under-predicted by more "
        f"than this fraction [-] (default {SHORT_TOLERANCE}; short is the unsafe side)",
    )
    calibrate.add_argument(
        "--workers",
        type=_positive_int,
        default=None,
        metavar="N",
        help="processes for the fits (default: all cores)",
    )
    calibrate.add_argument(
        "--distance-scatter",
        type=float,
        default=DISTANCE_SCATTER,
        metavar="X",
        help=f"relative scatter of the published distances [-] (default {DISTANCE_SCATTER})",
    )
    calibrate.add_argument(
        "--time-scatter",
        type=float,
        default=TIME_SCATTER,
        metavar="X",
        help=f"relative scatter of the published times [-] (default {TIME_SCATTER})",
    )
    calibrate.add_argument(
        "--leave-one-out",
        action="store_true",
        help="also fit without each joint's rows and predict them (use shared figures)",
    )
    calibrate.add_argument(
        "--robot-differs",
        action="store_true",
        help="fit TABLE to --robot although its robot column names another robot (names are "
        "compared by their letters and digits: UR5/CB3 is ur5_cb3 or ur5); every source in "
        "the outputs then says which robot the table was measured on",
    )
    calibrate.add_argument(
        "--out", type=_folder, required=True, metavar="DIR", help="output folder"
    )
    _output_options(calibrate)
    calibrate.set_defaults(func=_calibrate)


def _folder(text: str) -> Path:
    """An output folder's name: not empty (an empty name would write into this folder)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty name is not a folder; give --out DIR")
    return Path(text)


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{excerpt(text)}' is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} must be at least 1")
    return value


def _wrap(text: str) -> str:
    return textwrap.fill(text, width=88)


def _run(args: argparse.Namespace) -> int:
    scenario = _with_integrator_options(load_scenario(find_scenario(args.scenario)), args)
    out = args.out if args.out is not None else Path("results") / scenario.name
    try:
        check_output_folder(out)
    except OutputError as exc:
        raise ScenarioError("command line", "--out", exc.problem) from exc
    show = not (args.quiet or args.json)
    with _progress(scenario, show) as progress:
        output = run(scenario, transition=args.transition, compare=args.compare, progress=progress)
    try:
        written = write_outputs(output, out, figures={} if args.no_plots else None)
    except OutputError as exc:
        raise ScenarioError("command line", "--out", exc.problem) from exc
    if args.json:
        print(json.dumps(output.summary, indent=2, allow_nan=False))
    elif not args.quiet:
        print(format_summary(output.summary))
        for name, report in output.stopping.items():
            print()
            print(format_stopping(name, report))
        if output.figures is not None:
            print()
            print(format_figures(output.figures))
        print(f"\nwrote {out}/: {', '.join(written)}")
    return EXIT_OK


def _study(args: argparse.Namespace) -> int:
    if args.scheduler is None and (args.workers or default_workers()) > 1:
        start_fork_server()  # its imports overlap the reading of the study
    study = load_study(find_study(args.study))
    out = args.out if args.out is not None else Path("results") / study.name
    try:
        check_output_folder(out)
    except OutputError as exc:
        raise StudyError("command line", "--out", exc.problem) from exc
    _confirm_size(study, args.yes)
    show = not (args.quiet or args.json) and sys.stderr.isatty()
    begin = time.perf_counter()
    try:
        with _case_bar(study.name, show) as progress:
            output = run_study(
                study,
                out,
                workers=args.workers,
                scheduler=args.scheduler,
                progress=progress,
                engine=args.engine,
            )
    except KeyboardInterrupt:
        forget_interrupt()
        stored = count_stored(Path(out))
        print(
            f"vtm-pin: interrupted; {stored} finished cases are stored in {out}; run the same "
            "command again to continue",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    if args.json:
        print(json.dumps(output.summary, indent=2, allow_nan=False))
    elif not args.quiet:
        print(format_study(output, time.perf_counter() - begin))
        print(f"wrote {out}/: {', '.join(output.files)}")
    return EXIT_OK


#: Studies of more cases than this ask for confirmation (or ``--yes``): at the UR10's measured
#: 5 ms a case on 2 cores that is about 2 minutes of work; a bounded case costs several runs.
CONFIRM_CASES = 20_000


def _confirm_size(study: Study, yes: bool) -> None:
    """Ask before a study of more than :data:`CONFIRM_CASES` cases; refuse in a script."""
    count = study.size
    if count <= CONFIRM_CASES or yes:
        return
    question = f"study {study.name} has {count} cases (more than {CONFIRM_CASES}); run them?"
    if sys.stdin.isatty() and sys.stderr.isatty():
        print(f"vtm-pin: {question} [y/N] ", end="", file=sys.stderr, flush=True)
        if sys.stdin.readline().strip().lower() in ("y", "yes"):
            return
        raise StudyError(study.source, "", f"{count} cases not confirmed; nothing run")
    raise StudyError(
        study.source,
        "",
        f"{count} cases, more than {CONFIRM_CASES}: add --yes to run them from a script",
    )


def _calibrate(args: argparse.Namespace) -> int:
    for option, value in (
        ("--distance-scatter", args.distance_scatter),
        ("--time-scatter", args.time_scatter),
    ):
        if not (0.0 < value <= 10.0):
            raise ScenarioError("command line", option, f"{value} must be in (0, 10]")
    if not (0.0 <= args.short_tolerance < 1.0):
        raise ScenarioError(
            "command line", "--short-tolerance", f"{args.short_tolerance} must be in [0, 1)"
        )
    try:
        check_output_folder(args.out)
    except OutputError as exc:
        raise ScenarioError("command line", "--out", exc.problem) from exc
    table = check_table(
        read_stopping_table(args.table), args.robot, robot_differs=args.robot_differs
    )
    scatter = (args.distance_scatter, args.time_scatter)
    show = not (args.quiet or args.json) and sys.stderr.isatty()
    comparison, checks = _fit_or_compare(args, table, scatter, show)
    calibration = comparison.best.calibration
    summary = calibration_summary(calibration, table, checks, comparison)
    written = write_calibration(args.out, calibration, table, checks, summary, comparison)
    warning = warning_line(comparison)
    if warning is not None:
        warnings.warn(warning, VtmWarning, stacklevel=1)
    if args.json:
        print(json.dumps(summary, indent=2, allow_nan=False))
    elif not args.quiet:
        print(format_calibration(summary))
        print(f"wrote {args.out}/: {', '.join(written)}")
    return EXIT_OK


def _fit_or_compare(
    args: argparse.Namespace, table: Any, scatter: tuple[float, float], show: bool
) -> tuple[Comparison, list[LeftOut]]:
    """The classes compared (default), or the one set of figures --fit names, judged alike."""
    if args.fit is None:
        classes = [name.strip() for name in args.classes.split(",") if name.strip()]
        loo = {shared(CLASSES[c][1]) for c in classes if c in CLASSES}
        count = len(classes) + (len(loo) if len(table.joints) > 1 else 0)
        with tqdm(
            desc="fitting", unit="fit", total=count, file=sys.stderr, disable=not show
        ) as bar:

            def tick(_: str) -> None:
                bar.update(1)

            comparison = compare(
                table,
                args.robot,
                classes,
                scatter=scatter,
                short_tolerance=args.short_tolerance,
                workers=args.workers,
                progress=tick,
            )
        return comparison, []
    fit = [name.strip() for name in args.fit.split(",") if name.strip()]
    with tqdm(desc="fitting", unit="evaluation", file=sys.stderr, disable=not show) as bar:

        def progress(evaluations: int) -> None:
            bar.update(evaluations - bar.n)

        calibration = calibrate(table, args.robot, fit, scatter=scatter, progress=progress)
        checks = (
            leave_one_out(table, args.robot, fit, scatter=scatter) if args.leave_one_out else []
        )
    judged = judge("custom", f"--fit {','.join(fit)}", calibration, args.short_tolerance, checks)
    return recommend([judged], args.short_tolerance), checks


def _with_integrator_options(scenario: Scenario, args: argparse.Namespace) -> Scenario:
    """The scenario with --integrator / --dt / --rtol / --atol / --max-steps applied.

    The options are checked by the scenario's own rules (``integrator`` in the schema).
    """
    options = {
        "method": args.integrator,
        "dt": args.dt,
        "rtol": args.rtol,
        "atol": args.atol,
        "max_steps": args.max_steps,
    }
    overrides = {key: value for key, value in options.items() if value is not None}
    if not overrides:
        return scenario
    settings = integrator_settings(scenario.integrator)
    spec = {"method": overrides.get("method", scenario.integrator.name), **overrides}
    spec.setdefault("max_steps", settings.get("max_steps"))
    if spec["method"] == scenario.integrator.name:  # the same method keeps its output_dt
        spec.setdefault("output_dt", settings.get("output_dt"))
    if "method" not in overrides:
        spec = {**settings, **overrides}
    spec = {key: value for key, value in spec.items() if value is not None}
    try:
        integrator = build_integrator(spec, scenario.duration, "command line")
    except ScenarioError as exc:
        option = "--" + exc.key.split(".")[-1].replace("_", "-")
        raise ScenarioError("command line", option, exc.problem) from exc
    raw = {**scenario.raw, "integrator": spec}  # the bounds' variant runs use it too
    return dataclasses.replace(scenario, integrator=integrator, raw=raw)


class _ProgressBars:
    """Progress bars of simulated time on stderr, one per transition rule run in turn.

    A bar is drawn when ``show`` is set and stderr is a terminal, once its run has taken
    :data:`PROGRESS_DELAY` seconds.
    """

    def __init__(self, scenario: Scenario, show: bool) -> None:
        self.name = scenario.name
        self.total = scenario.duration  # [s]
        self.disable = not (show and sys.stderr.isatty())
        self.rule: str | None = None
        self.bar: tqdm | None = None
        self.reached = 0.0  # [s] simulated time the bar shows

    def __call__(self, rule: str, t: float) -> None:
        """Move the bar of ``rule`` to the simulated time ``t`` [s]."""
        if rule != self.rule:
            self.finish()
            self.rule, self.reached = rule, 0.0
            self.bar = tqdm(
                total=self.total,
                desc=f"{self.name} ({rule})",
                bar_format="{desc}: {percentage:3.0f}%|{bar}| t = {n:.3f} of {total:g} s "
                "[{elapsed} elapsed, {remaining} left]",
                delay=PROGRESS_DELAY,
                leave=False,
                file=sys.stderr,
                disable=self.disable,
            )
        if self.bar is not None and t >= self.reached + 1e-3 * self.total:  # <= 1000 updates
            self.bar.update(t - self.reached)
            self.reached = t

    def finish(self) -> None:
        """The current run is done: show 100 % before its bar goes."""
        if self.bar is not None:
            self.bar.update(self.total - self.reached)
            self.bar.refresh()
            self.close()

    def close(self) -> None:
        """Remove the current bar, if any."""
        if self.bar is not None:
            self.bar.close()
            self.bar = None


@contextmanager
def _progress(scenario: Scenario, show: bool) -> Iterator[Progress]:
    """A progress callback for :func:`~vtm_pin.outputs.pipeline.run`; bars go when it ends."""
    bars = _ProgressBars(scenario, show)
    try:
        yield bars
        bars.finish()
    finally:
        bars.close()


def _list(args: argparse.Namespace) -> int:
    if args.what == "scenarios":
        folder = args.dir or SCENARIOS_DIR
        rows = _scenario_rows(folder)
        header: list[object] = ["scenario", "robot", "duration [s]", "description"]
    elif args.what == "studies":
        folder = STUDIES_DIR
        rows = _study_rows()
        header = ["study", "scenario", "description"]
    elif args.what == "programs":
        folder = PROGRAMS_DIR
        rows = _program_rows()
        header = ["program", "rows", "duration [s]", "description"]
    else:
        folder = ROBOTS_DIR
        rows = _robot_rows(args.check, not args.json)
        header = ["robot", "joints", "tool frame", "source"]
    if args.json:
        print(json.dumps([dict(zip(map(str, header), row, strict=True)) for row in rows], indent=2))
        return EXIT_OK
    widths = [max(len(str(x)) for x in column) for column in zip(header, *rows, strict=True)]
    for row in [header, *rows]:
        cells = [str(x).ljust(w) for x, w in zip(row[:-1], widths[:-1], strict=True)]
        print("  ".join([*cells, str(row[-1])]))
    if args.dir is None:  # where the shipped files live
        kinds = {"scenarios": "scenario", "studies": "study", "robots": "robot"}
        kind = {**kinds, "programs": "program"}[args.what]
        print(f"\nin {folder} ('vtm-pin init {kind} NAME' copies one here)")
    if args.what == "robots" and not args.check:
        data = [n for n in shipped_names("robot") if (ROBOTS_DIR / f"{n}.yaml").is_file()]
        print(f"robot data files (drives, brakes, rated payload) there: {', '.join(data)}")
        names = ", ".join(list_example_robots())
        print(
            "\n"
            + _wrap(
                "example-robot-data names (fixed-base models whose joints are all 1-DoF load; "
                f"floating bases are refused; --check tries each): {names}"
            )
        )
    return EXIT_OK


def _program_rows() -> list[list[object]]:
    """The shipped programs: rows, duration and the first line of their comment header."""
    rows: list[list[object]] = []
    for name in shipped_names("program"):
        path = PROGRAMS_DIR / f"{name}.csv"
        lines = read_text(path, InputError).splitlines()
        comment = next((x.lstrip("# ").strip() for x in lines if x.startswith("#")), "")
        data = [x for x in lines if x.strip() and not x.startswith("#")][1:]
        duration = float(data[-1].split(",")[0]) - float(data[0].split(",")[0]) if data else 0.0
        rows.append([name, len(data), f"{duration:g}", comment])
    return rows


def _scenario_rows(folder: Path) -> list[list[object]]:
    rows: list[list[object]] = []
    for entry in list_scenarios(folder):
        duration = f"{entry.duration:g}" if math.isfinite(entry.duration) else "-"
        text = entry.description if entry.valid else f"INVALID: {entry.description}"
        rows.append([entry.name, entry.robot or "-", duration, text])
    return rows


def _study_rows() -> list[list[object]]:
    rows: list[list[object]] = []
    for name in shipped_names("study"):
        try:
            raw = read_yaml(STUDIES_DIR / f"{name}.yaml", StudyError)
            scenario, text = raw["scenario"], " ".join(str(raw.get("description", "")).split())
        except (VtmError, TypeError, KeyError) as exc:
            scenario, text = "-", f"INVALID: {exc}"
        rows.append([name, scenario, text])
    return rows


def _robot_rows(check: bool, show: bool) -> list[list[object]]:
    rows: list[list[object]] = []
    for name in list_local_robots():
        robot = load_robot(name)
        rows.append([name, robot.nv, robot.tool_frame, str(ROBOTS_DIR / f"{name}.urdf")])
    if check:
        names = list_example_robots()
        shown = show and sys.stderr.isatty()
        for name in tqdm(names, desc="loading", file=sys.stderr, disable=not shown, leave=False):
            try:
                robot = load_robot(name)
            except UnsupportedJoint as exc:
                rows.append([name, "-", "-", f"refused: joint '{exc.joint}' is a {exc.kind}"])
                continue
            except VtmError as exc:
                rows.append([name, "-", "-", f"refused: {str(exc).splitlines()[0]}"])
                continue
            rows.append([name, robot.nv, robot.tool_frame, "example-robot-data"])
    return rows


if __name__ == "__main__":
    sys.exit(main())

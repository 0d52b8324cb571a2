"""Study reports from synthetic results tables: Annex-B and distribution tables, stopping
graphs, the self-contained HTML page, and that page as a real browser (headless Chromium)
shows it. No simulation runs here: the tables come from a made-up braking formula.
"""

from __future__ import annotations

import base64
import html
import itertools
import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from matplotlib.image import imread

from vtm_pin.study.report import (
    FIGURE_DPI,
    annex_b_table,
    distribution_table,
    plot_stopping_graphs,
    render_report_html,
    write_study_report,
)

#: Synthetic robot: joint -> (velocity limit [rad/s], brake torque [N m], own inertia
#: [kg m^2], arm length from the joint to the tool at full extension [m], arm mass [kg]).
JOINTS = {
    "shoulder_pan_joint": (2.09, 150.0, 3.0, 1.3, 8.0),
    "shoulder_lift_joint": (2.09, 150.0, 3.5, 1.3, 8.0),
    "elbow_joint": (3.14, 56.0, 0.5, 0.6, 3.0),
}
SPEEDS = [0.33, 0.66, 1.0]  # [1] fraction of the velocity limit
PAYLOADS = [0.0, 5.0, 10.0]  # [kg]
EXTENSIONS = [0.33, 0.66, 1.0]  # [1] fraction of maximum reach
BRAKE_DELAY = 0.05  # [s] from the stop signal until the brake bites
#: The failed case of the grid and its message (with characters HTML must escape).
ERROR_CASE, ERROR_STATUS = "c005", "error: brake <model> diverged & stopped"
NOT_STOPPED_CASE = "c040"
#: Assumptions of the summary, one with characters HTML must escape.
ASSUMPTIONS = [
    "Brake torque < rated holding torque & constant while sliding",
    "Rotor inertias from the maker's data sheet",
]
#: Round-off: the same numbers computed in another order (or through decimal text).
RTOL = 1e-12
#: Longest a headless Chromium run may take [s]: it starts in about a second; a loaded CI
#: machine may take several, so this only catches a hang.
CHROMIUM_TIMEOUT = 120
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",  # needed as root (CI containers)
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
]


def braking(joint: str, speed: float, payload: float, extension: float) -> dict[str, float]:
    """Made-up constant-torque braking after a delay: stop time [s], angle [rad], distances."""
    v_max, torque, inertia, length, arm = JOINTS[joint]
    radius = extension * length  # [m] tool distance from the joint axis
    inertia += (payload + arm / 3.0) * radius**2  # [kg m^2]
    v = speed * v_max  # [rad/s]
    deceleration = torque / inertia  # [rad/s^2]
    angle = v * BRAKE_DELAY + v**2 / (2.0 * deceleration)
    return {
        "robot_stop_time": BRAKE_DELAY + v / deceleration,
        "stop_angle": angle,
        "tcp_max_displacement": 2.0 * radius * np.sin(angle / 2.0),  # chord of the arc
        "tcp_path": radius * angle,
        "peak_tcp_speed": v * radius,
    }


def case_row(case: str, axes: dict[str, object]) -> dict[str, object]:
    """One ok row of a results table, columns in the study's order."""
    joint = str(axes["joint"])
    result = braking(joint, *(float(axes[k]) for k in ("speed", "payload", "extension")))
    row: dict[str, object] = {"case": case, **axes, "status": "ok", **result}
    for other in JOINTS:
        row[f"stop_time.{other}"] = result["robot_stop_time"] if other == joint else 0.0
        row[f"stop_angle.{other}"] = result["stop_angle"] if other == joint else 0.0
    row["wall_time"] = 0.25
    return row


def grid_table() -> pd.DataFrame:
    """3 joints x 3 payloads x 3 extensions x 3 speeds, one error and one not-stopped case,
    rows shuffled (the report must sort them)."""
    product = itertools.product(JOINTS, PAYLOADS, EXTENSIONS, SPEEDS)
    rows = [
        case_row(f"c{k:03d}", {"joint": j, "speed": s, "payload": p, "extension": e})
        for k, (j, p, e, s) in enumerate(product)
    ]
    table = pd.DataFrame(rows).set_index("case", drop=False)
    results = [
        "robot_stop_time",
        "stop_angle",
        "tcp_max_displacement",
        "tcp_path",
        "peak_tcp_speed",
    ]
    table.loc[ERROR_CASE, "status"] = ERROR_STATUS
    table.loc[ERROR_CASE, results] = np.nan
    table.loc[NOT_STOPPED_CASE, "status"] = "not_stopped"
    table.loc[NOT_STOPPED_CASE, "robot_stop_time"] = np.nan  # angle and distance so far stay
    return table.sample(frac=1.0, random_state=3).reset_index(drop=True)


def sampled_table(n: int = 240, seed: int = 7) -> pd.DataFrame:
    """Two joints, two stop categories, speed, payload and extension drawn from ranges."""
    rng = np.random.default_rng(seed)
    rows = []
    for k in range(n):
        axes = {
            "category": int(rng.integers(0, 2)),
            "joint": str(rng.choice(["shoulder_pan_joint", "elbow_joint"])),
            "speed": float(rng.uniform(0.1, 1.0)),
            "payload": float(rng.uniform(0.0, 10.0)),
            "extension": float(rng.uniform(0.2, 1.0)),
        }
        rows.append(case_row(f"s{k:03d}", axes))
    table = pd.DataFrame(rows)
    table.loc[3, ["status", "robot_stop_time"]] = ["not_stopped", np.nan]
    table.loc[4, ["status", "robot_stop_time", "stop_angle", "tcp_max_displacement"]] = [
        "error: no contact",
        np.nan,
        np.nan,
        np.nan,
    ]
    return table


def summary(mode: str = "grid") -> dict[str, object]:
    axes: dict[str, object] = {"speed": SPEEDS, "payload": PAYLOADS, "extension": EXTENSIONS}
    if mode == "sampled":
        axes = {"speed": {"min": 0.1, "max": 1.0}, "category": [0, 1]}
    return {
        "study": {
            "name": "ur10-annex-b",
            "file": "ur10_annex_b.yaml",
            "description": "UR10 stopping distances & times, Annex B grid",
            "scenario": "ur10_stop.yaml",
            "robot": "ur10",
            "tool_frame": "tool0",
            "mode": mode,
            "samples": None,
            "seed": 7,
            "axes": axes,
        },
        "counts": {"cases": 81, "ok": 79, "not_stopped": 1, "error": 1},
        "versions": {"vtm_pin": "0.1.0", "pinocchio": "3.4.0"},
        "assumptions": ASSUMPTIONS,
        "definitions": {"wall_time": "Computing time of the case, one core."},
        "units": {"wall_time": "s"},
    }


@pytest.fixture(scope="module")
def grid() -> pd.DataFrame:
    return grid_table()


@pytest.fixture(scope="module")
def sampled() -> pd.DataFrame:
    return sampled_table()


@pytest.fixture(scope="module")
def grid_figures(grid):
    return plot_stopping_graphs(grid, robot="ur10")


@pytest.fixture(scope="module")
def report(grid, tmp_path_factory) -> tuple[Path, list[str]]:
    folder = tmp_path_factory.mktemp("report")
    return folder, write_study_report(folder, summary(), grid)


# --- tables ------------------------------------------------------------------------------


def test_annex_b_table_rows_order_columns_and_units(grid):
    out = annex_b_table(grid)
    assert list(out.columns) == [
        "joint",
        "payload [kg]",
        "extension [%]",
        "speed [%]",
        "robot_stop_time [s]",
        "stop_angle [rad]",
        "stop_angle [deg]",
        "tcp_max_displacement [m]",
        "status",
        "case",
    ]
    assert len(out) == len(grid) == 81
    joints = list(dict.fromkeys(grid["joint"]))  # joints in the order the table names them
    expected = sorted(
        grid.itertuples(),
        key=lambda r: (joints.index(r.joint), r.payload, r.extension, r.speed),
    )
    assert list(out["case"]) == [r.case for r in expected]
    source = grid.set_index("case").loc[out["case"]]
    np.testing.assert_allclose(out["speed [%]"], 100.0 * source["speed"], rtol=RTOL)
    np.testing.assert_allclose(out["extension [%]"], 100.0 * source["extension"], rtol=RTOL)
    np.testing.assert_array_equal(out["payload [kg]"], source["payload"])
    ok = (source["status"] == "ok").to_numpy()
    for label, column in [
        ("robot_stop_time [s]", "robot_stop_time"),
        ("stop_angle [rad]", "stop_angle"),
        ("tcp_max_displacement [m]", "tcp_max_displacement"),
    ]:
        np.testing.assert_allclose(out[label][ok], source[column][ok], rtol=RTOL)
    np.testing.assert_allclose(
        out["stop_angle [deg]"][ok], np.degrees(source["stop_angle"][ok]), rtol=RTOL
    )
    failed = out.set_index("case").loc[[ERROR_CASE, NOT_STOPPED_CASE]]
    results = [
        "robot_stop_time [s]",
        "stop_angle [rad]",
        "stop_angle [deg]",
        "tcp_max_displacement [m]",
    ]
    assert failed[results].isna().all().all()  # not-stopped angle and distance hidden too
    assert list(failed["status"]) == [ERROR_STATUS, "not_stopped"]


def test_annex_b_table_sorts_by_category_first_and_keeps_other_axes():
    rows = [
        case_row(f"k{k}", {"joint": j, "speed": s, "payload": 5.0, "extension": 1.0})
        for k, (j, s) in enumerate(itertools.product(["elbow_joint", "shoulder_pan_joint"], SPEEDS))
    ]
    table = pd.DataFrame(rows)
    table.insert(1, "category", [1, 0] * 3)
    table.insert(2, "brake_scale", [0.8, 1.0, 1.2] * 2)
    out = annex_b_table(table.iloc[::-1])
    assert list(out.columns[:6]) == [
        "category",
        "joint",
        "payload [kg]",
        "extension [%]",
        "speed [%]",
        "brake_scale",
    ]
    keys = list(zip(out["category"], out["joint"], out["speed [%]"], strict=True))
    # Joints in order of first appearance in the (reversed) table: shoulder_pan_joint first.
    order = {"shoulder_pan_joint": 0, "elbow_joint": 1}
    assert keys == sorted(keys, key=lambda k: (k[0], order[k[1]], k[2]))


def test_distribution_table_matches_numpy(sampled):
    out = distribution_table(sampled)
    assert len(out) == 4  # 2 categories x 2 joints
    assert list(out["category"]) == [0, 0, 1, 1]
    for values in out.to_dict("records"):
        group = sampled[
            (sampled["category"] == values["category"]) & (sampled["joint"] == values["joint"])
        ]
        ok = group[group["status"] == "ok"]
        assert values["cases"] == len(group)
        assert values["ok"] == len(ok)
        assert values["not_stopped"] == (group["status"] == "not_stopped").sum()
        assert values["error"] == group["status"].str.startswith("error").sum()
        for name, unit in [
            ("robot_stop_time", "s"),
            ("stop_angle", "rad"),
            ("tcp_max_displacement", "m"),
        ]:
            v = np.abs(ok[name].to_numpy(float))
            np.testing.assert_allclose(values[f"{name} median [{unit}]"], np.median(v), rtol=RTOL)
            np.testing.assert_allclose(
                values[f"{name} p95 [{unit}]"], np.percentile(v, 95.0), rtol=RTOL
            )
            np.testing.assert_allclose(values[f"{name} max [{unit}]"], np.max(v), rtol=RTOL)


# --- graphs ------------------------------------------------------------------------------


def test_stopping_graphs_panels_curves_and_failed_cases(grid, grid_figures):
    assert set(grid_figures) == {f"stopping_{joint}.png" for joint in JOINTS}
    for joint in JOINTS:
        fig = grid_figures[f"stopping_{joint}.png"]
        axes = fig.axes
        assert len(axes) == 2 * len(EXTENSIONS)  # two rows x one column per extension
        assert [ax.get_title() for ax in axes[: len(EXTENSIONS)]] == [
            f"extension {100 * e:.3g} % of reach" for e in EXTENSIONS
        ]
        assert "SIMULATED" in fig._suptitle.get_text() and joint in fig._suptitle.get_text()
        for k, ax in enumerate(axes):
            lines = ax.get_lines()
            assert [line.get_label() for line in lines] == [f"payload {p:g} kg" for p in PAYLOADS]
            extension = EXTENSIONS[k % len(EXTENSIONS)]
            column = "stop_angle" if k < len(EXTENSIONS) else "robot_stop_time"
            for line, payload in zip(lines, PAYLOADS, strict=True):
                rows = grid[
                    (grid["joint"] == joint)
                    & (grid["payload"] == payload)
                    & (grid["extension"] == extension)
                    & (grid["status"] == "ok")
                ].sort_values("speed")
                np.testing.assert_allclose(line.get_xdata(), 100.0 * rows["speed"], rtol=RTOL)
                np.testing.assert_allclose(line.get_ydata(), rows[column], rtol=RTOL)
    for case in [ERROR_CASE, NOT_STOPPED_CASE]:  # a failed case leaves its curve short
        row = grid.set_index("case").loc[case]
        fig = grid_figures[f"stopping_{row['joint']}.png"]
        ax = fig.axes[EXTENSIONS.index(row["extension"])]
        (line,) = [li for li in ax.get_lines() if li.get_label() == f"payload {row.payload:g} kg"]
        assert len(line.get_xdata()) == len(SPEEDS) - 1
        assert 100.0 * row["speed"] not in list(line.get_xdata())


def test_stopping_graphs_without_payload_or_extension_axis(grid):
    one = grid[(grid["payload"] == 5.0) & (grid["extension"] == 1.0)]
    figures = plot_stopping_graphs(one.drop(columns=["payload", "extension"]))
    fig = figures["stopping_elbow_joint.png"]
    assert len(fig.axes) == 2  # one column
    assert [len(ax.get_lines()) for ax in fig.axes] == [1, 1]  # one curve


def test_sampled_graphs_scatter_by_category_with_binned_extension(sampled):
    figures = plot_stopping_graphs(sampled, robot="ur10")
    assert set(figures) == {
        f"stopping_{joint}_cat{c}.png"
        for joint in ("shoulder_pan_joint", "elbow_joint")
        for c in (0, 1)
    }
    edges = np.linspace(sampled["extension"].min(), sampled["extension"].max(), 4)
    for name, fig in figures.items():
        joint, category = re.fullmatch(r"stopping_(.+)_cat(\d)\.png", name).groups()
        group = sampled[(sampled["joint"] == joint) & (sampled["category"] == int(category))]
        panels, colourbar = fig.axes[:6], fig.axes[6:]
        assert len(colourbar) == 1 and colourbar[0].get_ylabel() == "payload [kg]"
        titles = [ax.get_title() for ax in panels[:3]]
        assert titles[0].startswith(f"extension [{100 * edges[0]:.3g}, {100 * edges[1]:.3g})")
        assert titles[2].startswith(f"extension [{100 * edges[2]:.3g}, {100 * edges[3]:.3g}]")
        assert all(not ax.get_lines() for ax in panels)  # points, no lines
        drawn = sum(len(c.get_offsets()) for ax in panels[:3] for c in ax.collections)
        assert drawn == (group["status"] == "ok").sum()
        assert f"stop category {category}" in fig._suptitle.get_text()


# --- HTML --------------------------------------------------------------------------------


def table_rows(page: str, table_id: str) -> list[str]:
    """Body rows of the HTML table with this id."""
    body = re.search(rf'<table id="{table_id}">.*?<tbody>(.*?)</tbody>', page, re.S)
    assert body is not None, table_id
    return re.findall(r"<tr>.*?</tr>", body.group(1), re.S)


def test_report_html_content_escaping_and_self_contained(grid, report):
    folder, _ = report
    page = (folder / "report.html").read_text(encoding="utf-8")
    for assumption in ASSUMPTIONS:
        assert f"<li>{html.escape(assumption)}</li>" in page
    assert "Brake torque < rated" not in page  # the raw '<' never reaches the page
    assert "T_robot — the robot's own stopping time" in html.unescape(page)
    assert "S = K·T + D_DS + Z" in page and "T = t_detection + t_response + t_latency" in page
    assert "T_robot alone is NOT T" in page  # the summary gives no safeguard times
    assert "S_s — stopping distance" in page and "ISO/TS 15066" in page
    annex = annex_b_table(grid)
    rows = table_rows(page, "annex-b")
    assert len(rows) == len(annex)
    for row, case in zip(rows, annex["case"], strict=True):
        assert f"<td>{case}</td>" in row
    (error_row,) = [r for r in rows if f"<td>{ERROR_CASE}</td>" in r]
    assert error_row.count('<td class="num">—</td>') == 4  # NaN results shown as "—"
    failures = table_rows(page, "failures")
    assert len(failures) == 2
    assert any(html.escape("brake <model> diverged & stopped") in r for r in failures)
    columns = table_rows(page, "columns")
    assert [re.search(r"<td>(.*?)</td>", r).group(1) for r in columns] == list(grid.columns)
    assert "Computing time of the case, one core." in page  # summary definitions win
    assert "pinocchio" in page and "3.4.0" in page
    assert html.escape("UR10 stopping distances & times, Annex B grid") in page
    # Self-contained: no links to anything, no script; the images are the PNGs themselves.
    assert "http://" not in page and "https://" not in page
    assert "<script" not in page and "url(" not in page
    sources = re.findall(r'<img src="([^"]*)"', page)
    pngs = sorted(p for p in os.listdir(folder) if p.endswith(".png"))
    assert len(sources) == len(pngs) == 3
    prefix = "data:image/png;base64,"
    assert all(s.startswith(prefix) for s in sources)
    embedded = {base64.b64decode(s[len(prefix) :]) for s in sources}
    assert embedded == {(folder / p).read_bytes() for p in pngs}


def test_report_html_sampled_shows_distribution(sampled):
    page = render_report_html(summary("sampled"), sampled, {})
    assert len(table_rows(page, "distribution")) == 4
    assert 'id="annex-b"' not in page
    assert "range 0.1 … 1" in page  # a sampled axis is shown as its range


def test_write_study_report_files(grid, grid_figures, report):
    folder, written = report
    assert written == sorted(os.listdir(folder))
    assert written == sorted(["annex_b_table.csv", "report.html", *grid_figures])
    csv = pd.read_csv(folder / "annex_b_table.csv")
    # Decimal text round-trips a float to round-off.
    pd.testing.assert_frame_equal(csv, annex_b_table(grid), check_dtype=False, rtol=RTOL)
    for name, fig in grid_figures.items():
        height, width = imread(folder / name).shape[:2]
        assert (width, height) == tuple(np.round(fig.get_size_inches() * FIGURE_DPI).astype(int))


def test_write_study_report_sampled_writes_distribution(sampled, tmp_path):
    few = sampled[sampled["joint"] == "elbow_joint"]
    written = write_study_report(tmp_path, summary("sampled"), few)
    assert written == [
        "distribution.csv",
        "report.html",
        "stopping_elbow_joint_cat0.png",
        "stopping_elbow_joint_cat1.png",
    ]


# --- in a browser ------------------------------------------------------------------------

#: Appended to a copy of the page: once loaded, it writes what the browser shows into the DOM.
PROBE = """<script>
window.addEventListener("load", () => {
  const shown = [...document.images].filter((i) => i.complete && i.naturalWidth > 0).length;
  const probe = document.createElement("pre");
  probe.id = "probe";
  probe.textContent = JSON.stringify({
    images: shown, rows: document.querySelectorAll("tr").length,
    tables: document.querySelectorAll("table").length});
  document.body.appendChild(probe);
});
</script>"""


def chromium() -> str:
    """Path of the Chromium browser; skips without it, but fails in CI (it installs it)."""
    found = shutil.which("chromium") or (
        "/usr/bin/chromium" if os.access("/usr/bin/chromium", os.X_OK) else None
    )
    if found is None:
        if os.environ.get("CI"):
            pytest.fail("chromium is missing in CI, which installs it (.ci/run)")
        pytest.skip("chromium is not installed (CI installs it)")
    return found


def run_chromium(browser: str, tmp_path: Path, name: str, *args: str) -> str:
    profile = tmp_path / f"profile-{name}"  # a new empty profile for every run
    profile.mkdir()
    done = subprocess.run(
        [browser, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", *args],
        capture_output=True,
        text=True,
        timeout=CHROMIUM_TIMEOUT,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


def test_chromium_shows_tables_and_images(report, tmp_path):
    browser = chromium()
    folder, _ = report
    page = (folder / "report.html").read_text(encoding="utf-8")
    probed = tmp_path / "probed.html"
    probed.write_text(page.replace("</body>", PROBE + "\n</body>"), encoding="utf-8")
    dom = run_chromium(browser, tmp_path, "dom", "--dump-dom", probed.as_uri())
    found = re.search(r'<pre id="probe">(.*?)</pre>', dom)
    assert found is not None, dom[-2000:]
    shown = json.loads(html.unescape(found.group(1)))
    assert shown["images"] == 3  # every embedded PNG decoded (a broken one has width 0)
    assert shown["rows"] == page.count("<tr>") > 81
    assert shown["tables"] == page.count("<table ")
    # And it is drawn: a screenshot of the top of the page is not blank.
    shot = tmp_path / "shot.png"
    run_chromium(
        browser,
        tmp_path,
        "shot",
        "--window-size=1200,1600",
        f"--screenshot={shot}",
        (folder / "report.html").as_uri(),
    )
    pixels = imread(shot)[..., :3]
    assert pixels.shape[:2] == (1600, 1200)
    not_white = np.any(pixels < 0.9, axis=-1).mean()
    # Text, tables and a graph cover a few per cent of the top of the page at least.
    assert not_white > 0.02
    rgb = (pixels * 255).round().astype(np.int64) @ np.array([1 << 16, 1 << 8, 1])
    assert np.unique(rgb).size > 50  # a graph's curves, anti-aliased text: many colours


def test_graphs_drawn_in_a_process_of_their_own_are_the_same_files(grid, report, tmp_path):
    """A study on several workers draws its graphs in a process of its own while it writes
    its tables (`vtm_pin.study.runner._finish`): the same PNG bytes as drawn here, and the
    same report page."""
    from vtm_pin.study.executors import in_background
    from vtm_pin.study.report import stopping_images

    folder, written = report
    with in_background(stopping_images, grid, "ur10") as future:
        images = future.result()
    assert sorted(images) == sorted(n for n in written if n.endswith(".png"))
    for name, data in images.items():
        assert data == (folder / name).read_bytes(), name
    again = write_study_report(tmp_path, summary(), grid, images)
    assert again == written
    assert (tmp_path / "report.html").read_text() == (folder / "report.html").read_text()


@pytest.mark.parametrize("processes", [2, 3, 4])
def test_graphs_drawn_in_shares_are_the_one_process_graphs_in_order(grid, report, processes):
    """A study on n workers draws its graphs in n processes, a share each
    (`vtm_pin.study.runner._images`): merged, the same PNG bytes under the same names in the
    same order as one process draws them (the grid has three; with four processes one
    draws none)."""
    from vtm_pin.study.report import merge_shares, stopping_images

    folder, _ = report
    alone = stopping_images(grid, "ur10")
    shares = [stopping_images(grid, "ur10", (k, processes)) for k in range(processes)]
    assert sum(len(share) for share in shares) == len(alone) == 3
    merged = merge_shares(shares)
    assert list(merged) == list(alone)
    assert merged == alone
    for name, data in merged.items():
        assert data == (folder / name).read_bytes(), name

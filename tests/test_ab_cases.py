"""benchmarks/ab_cases.py: two trees alternated on the same cases, paired by round."""

import subprocess
import sys

import pytest
from conftest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))
from ab_cases import NEW, OLD, PARTS, compare, extract, order

HAS_GIT = (ROOT / ".git").exists()


def test_the_trees_run_in_abba_order_one_of_each_a_round():
    assert order(3) == [OLD, NEW, NEW, OLD, OLD, NEW]
    for r in range(3):
        assert sorted(order(3)[2 * r : 2 * r + 2]) == sorted([OLD, NEW])


def test_rounds_are_paired_in_the_order_they_ran():
    def parts(ms):
        return dict.fromkeys(PARTS, ms / len(PARTS))

    ran = [(OLD, parts(3.0)), (NEW, parts(1.5)), (NEW, parts(2.0)), (OLD, parts(2.0))]
    result = compare(ran)
    assert result.old == pytest.approx((3.0, 2.0))
    assert result.new == pytest.approx((1.5, 2.0))
    assert result.ratios == pytest.approx((0.5, 1.0))
    assert result.median == pytest.approx(0.75)
    assert result.parts[NEW]["build"] == pytest.approx(0.5 * (0.5 + 2.0 / 3.0))
    with pytest.raises(ValueError, match="one figure of each"):
        compare(ran[:3])


@pytest.mark.skipif(not HAS_GIT, reason="not a git clone: nothing to archive")
def test_the_tree_at_a_commit_is_extracted_with_its_data_inside_its_package(tmp_path):
    extract("HEAD", tmp_path)
    assert (tmp_path / "vtm_pin" / "__init__.py").is_file()
    assert (tmp_path / "vtm_pin" / "robots").resolve() == (tmp_path / "robots").resolve()
    assert any((tmp_path / "vtm_pin" / "studies").glob("*.yaml"))


@pytest.mark.skipif(not HAS_GIT, reason="not a git clone: nothing to archive")
def test_a_ref_that_is_not_a_commit_is_one_line_and_exit_1():
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "ab_cases.py"), "--against", "no-such-ref"],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 1
    assert done.stdout == ""
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "no-such-ref" in lines[0] and "Traceback" not in lines[0]

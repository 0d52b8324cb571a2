"""benchmarks/interleaved.py: two versions alternated on the same cases, paired by round."""

import subprocess
import sys

import pytest
from conftest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))
from interleaved import NEW, OLD, PARTS, compare, order, tree

HAS_GIT = (ROOT / ".git").exists()


def test_the_versions_run_in_abba_order_one_of_each_a_round():
    assert order(3) == [NEW, OLD, OLD, NEW, NEW, OLD]
    for r in range(3):
        assert sorted(order(3)[2 * r : 2 * r + 2]) == sorted([NEW, OLD])


def test_rounds_are_paired_in_the_order_they_ran():
    def parts(ms):
        return dict.fromkeys(PARTS, ms / len(PARTS))

    ran = [(NEW, parts(1.5)), (OLD, parts(3.0)), (OLD, parts(2.0)), (NEW, parts(2.0))]
    result = compare(ran)
    assert result.new == pytest.approx((1.5, 2.0))
    assert result.old == pytest.approx((3.0, 2.0))
    assert result.ratios == pytest.approx((0.5, 1.0))
    assert result.median == pytest.approx(0.75)
    assert result.parts[NEW]["build"] == pytest.approx(0.5 * (0.5 + 2.0 / 3.0))
    with pytest.raises(ValueError, match="one figure of each"):
        compare(ran[:3])


def test_a_checkout_is_taken_as_it_is(tmp_path):
    assert tree(str(ROOT), tmp_path / "unused") == ROOT
    assert not (tmp_path / "unused").exists()


@pytest.mark.skipif(not HAS_GIT, reason="not a git clone: nothing to archive")
def test_a_commit_is_extracted_with_its_data_inside_its_package(tmp_path):
    folder = tree("HEAD", tmp_path / "head")
    assert (folder / "vtm_pin" / "__init__.py").is_file()
    assert (folder / "vtm_pin" / "robots").resolve() == (folder / "robots").resolve()
    assert any((folder / "vtm_pin" / "studies").glob("*.yaml"))


@pytest.mark.skipif(not HAS_GIT, reason="not a git clone: nothing to archive")
def test_a_version_that_is_neither_is_one_line_and_exit_1():
    script = str(ROOT / "benchmarks" / "interleaved.py")
    done = subprocess.run(
        [sys.executable, script, "no-such-ref", "HEAD"], capture_output=True, text=True
    )
    assert done.returncode == 1
    assert done.stdout == ""
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "no-such-ref" in lines[0] and "Traceback" not in lines[0]

"""LaserScans whose range_max is +inf: the driver sets no limit (ROS 2's
pointcloud_to_laserscan by default sends a double's maximum, inf as float32). Read as the
largest float32 (every finite return a return) and counted; NaN or 0 stays refused."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_bag import bag_with

from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.recordings.bag import NO_RANGE_LIMIT_M, import_bag
from rigcal.recordings.sequence import read_sequence


@pytest.mark.parametrize("ros", [1, 2])
def test_a_range_max_of_inf_is_no_limit(tmp_path, ros):
    ranges = np.full(11, 2.0, np.float32)
    ranges[[2, 5, 8]] = [np.inf, 0.0, 1000.0]  # no return, no return, a far return
    bag = bag_with(
        tmp_path / ("b.bag" if ros == 1 else "b"), ros, scan={"range_max": np.inf, "ranges": ranges}
    )
    s = import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")
    assert s.scan_counts["range_max_inf"] == 2
    assert "2 scans with range_max inf (no limit)" in s.notes()
    seq = read_sequence(tmp_path / "seq")
    assert seq.source["range_max_inf"] == 2
    scan = seq.scans[0]
    assert scan.range_max_m == NO_RANGE_LIMIT_M
    assert scan.valid.tolist() == [k not in (2, 5) for k in range(11)]
    np.testing.assert_allclose(scan.ranges_m[8], 1000.0)


def test_the_import_says_so_and_json_counts_it(tmp_path, capsys):
    bag = bag_with(tmp_path / "b", 2, scan={"range_max": np.inf})
    argv = ["-q", "import-bag", str(bag), "--scan-topic", "/scan", "--image-topic", "/cam/image", "--json"]
    assert main([*argv, "-o", str(tmp_path / "seq")]) == 0
    assert json.loads(capsys.readouterr().out)["range_max_inf"] == 2


@pytest.mark.parametrize(("value", "shown"), [(np.nan, "nan"), (0.0, "0.0"), (-np.inf, "-inf")])
def test_a_range_max_of_nan_zero_or_minus_inf_is_refused(tmp_path, value, shown):
    bag = bag_with(tmp_path / "b", 2, scan={"range_max": value})
    with pytest.raises(
        InputError, match=rf"b: /scan message 0: range_max: got {shown}; expected a finite number > 0"
    ):
        import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")
    assert not (tmp_path / "seq").exists()

"""A CARMEN laser line's reading of exactly its maximum range is no return (CARMEN writes
the maximum where nothing came back), as readings beyond it are: never a ring of points at
the scanner's range around every pose."""

from __future__ import annotations

import numpy as np
from test_carmen import flaser, robotlaser1, write

from rigcal.recordings.carmen import read_carmen


def test_readings_at_the_maximum_range_are_no_return(tmp_path):
    ranges = [2.0, 50.0, 3.0, 50.0001, 49.99]
    log = read_carmen(write(tmp_path, [robotlaser1(ranges), flaser([4.0, 50.0, 5.0, 6.0], stamp=100.1)]))
    rl, fl = log.scans
    assert rl.valid.tolist() == [True, False, True, False, True]
    assert np.isinf(rl.ranges_m[1])
    assert fl.valid.tolist() == [True, False, True, True]  # FLASER: --flaser-range-max-m, 50 m
    log = read_carmen(write(tmp_path, [flaser([4.0, 50.0, 5.0, 6.0])], "b.log"), flaser_range_max_m=60.0)
    assert log.scans[0].valid.all()

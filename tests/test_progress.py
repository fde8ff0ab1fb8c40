"""A long job's progress in its log (hybridtwin.progress, issue 55): the count, the time so far and the time left,
on a clock the test drives (no sleeping, no timing of this machine)."""

import logging

import pytest

from hybridtwin.progress import Progress, duration


class Clock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


def test_the_time_left_is_the_mean_time_per_item_times_the_items_left(caplog):
    clock = Clock()
    log = logging.getLogger("test_progress")
    progress = Progress(log, 8, "runs' libraries", clock=clock)
    assert progress.left_s() != progress.left_s()  # NaN before the first item: nothing to estimate from
    clock.now += 30.0  # three items in 30 s: 10 s each, five left
    with caplog.at_level(logging.INFO, logger="test_progress"):
        line = progress.done(3, note="r950_m0p0")
    assert progress.left_s() == pytest.approx(50.0)
    assert line == "3 of 8 runs' libraries (38 %) after 30 s, about 50 s left (r950_m0p0)"
    assert caplog.records[-1].getMessage() == line
    clock.now += 570.0  # 600 s for 8: the last line has no time left
    assert progress.done(5) == "8 of 8 runs' libraries (100 %) after 10.0 min"


@pytest.mark.parametrize("seconds, text", [(41.2, "41 s"), (89.0, "89 s"), (138.0, "2.3 min"), (5399.0, "90.0 min"),
                                           (4320.0, "72.0 min"), (7560.0, "2.1 h")])
def test_durations_read_as_a_person_reads_them(seconds, text):
    assert duration(seconds) == text


def test_no_logger_still_counts():
    clock = Clock()
    progress = Progress(None, 2, "thorough refits", clock=clock)
    clock.now += 4.0
    assert progress.done() == "1 of 2 thorough refits (50 %) after 4 s, about 4 s left"

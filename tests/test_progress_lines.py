"""Progress lines for logs: runs done, runs left, the time left estimated from this process's runs."""

import io

from uiest.progress_lines import ProgressLines, duration


class Clock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


def test_lines_count_done_and_left_and_estimate_the_time_left_from_the_runs_computed_here():
    clock, stream = Clock(), io.StringIO()
    lines = ProgressLines("study", 10, done=4, interval=30.0, stream=stream, clock=clock)
    clock.now += 20.0
    lines.advance()  # the first line at once
    clock.now += 20.0
    lines.advance()  # 20 s after the last line: too soon
    clock.now += 20.0
    lines.advance()  # 40 s after the last line
    clock.now += 1.0
    lines.advance(3)  # the last line at once
    assert stream.getvalue().splitlines() == [
        "study: 5 of 10 runs done (4 stored before), 5 left, about 1 min 40 s left",  # 20 s per run computed here
        "study: 7 of 10 runs done (4 stored before), 3 left, about 1 min 0 s left",
        "study: 10 of 10 runs done (4 stored before), 0 left",
    ]


def test_durations_read_as_seconds_minutes_or_hours():
    assert [duration(s) for s in (0.4, 59.6, 61, 3599, 3600, 7380)] == [
        "0 s", "1 min 0 s", "1 min 1 s", "59 min 59 s", "1 h 0 min", "2 h 3 min"
    ]  # fmt: skip


def test_runs_without_a_result_are_counted_lost_neither_done_nor_left():
    # a sweep's refused tasks were counted done: "12 of 12 tasks done, 0 left" beside "6 lost"
    clock, stream = Clock(), io.StringIO()
    lines = ProgressLines("sweep", 4, interval=0.0, stream=stream, clock=clock, unit="tasks")
    clock.now += 10.0
    lines.advance()
    clock.now += 10.0
    lines.advance(0, lost=1)
    clock.now += 10.0
    lines.advance(1, lost=1)
    assert stream.getvalue().splitlines() == [
        "sweep: 1 of 4 tasks done, 3 left, about 30 s left",
        "sweep: 1 of 4 tasks done, 1 lost, 2 left, about 20 s left",  # 10 s per task ended here, with or without rows
        "sweep: 2 of 4 tasks done, 2 lost, 0 left",
    ]

"""hil.runtime.clock.RunClock: the run's one time base, simulated = (t − t0) · speed, on the monotonic clock
and on the trace's; each conversion is the arithmetic the runners and the report did before it had a home,
operation for operation (issue 45), so the figures they give stay bit for bit."""

from __future__ import annotations

import time

import numpy as np
import pytest

from hil.runtime.clock import LOCKSTEP_CLOCK, RunClock

T0_S = 1_796_556_887.138472           # a real-time run's start on the wall clock (run.json trace_t0_s)


@pytest.mark.parametrize("speed", [1.0, 0.5, 0.25, 0.3])
def test_trace_times_convert_as_the_report_and_the_hosts_did(speed):
    clock = RunClock(T0_S, speed)
    t = T0_S + np.array([0.0, 0.0123456, 1.5, 17.000001, 123.456789])
    assert np.array_equal(clock.simulated_s(t), (t - T0_S) * speed)
    for x in t.tolist():
        assert clock.simulated_s(x) == (x - T0_S) * speed
        assert clock.simulated_us(x) == int((x - T0_S) * (1e6 * speed))        # hil.runtime.host's
    for end_us in (0, 1, 999_999, 12_345_678):
        assert clock.trace_s(end_us) == T0_S + end_us / 1e6 / speed


@pytest.mark.parametrize("speed", [1.0, 0.5, 0.3])
def test_the_monotonic_clock_converts_as_the_hosts_did(speed):
    t0_ns = time.monotonic_ns()
    clock = RunClock.starting(t0_ns, speed)
    for sim_ns in (0, 1_000, 10_000_000, 123_456_789):
        assert clock.deadline_ns(sim_ns) == t0_ns + round(sim_ns / speed)
    before = int((time.monotonic_ns() - t0_ns) * speed) // 1000
    now = clock.now_us()
    assert before <= now <= int((time.monotonic_ns() - t0_ns) * speed) // 1000
    assert clock.wall_s(2.0) == 2.0 / speed
    assert abs(clock.t0_s - time.time()) < 1.0 and clock.t0_ns == t0_ns


@pytest.mark.parametrize("meta, expected", [
    ({"mode": "lockstep", "trace_t0_s": 0.0, "scenario": {"realtime": {"speed": 0.5}}}, (0.0, 1.0)),
    ({"mode": "realtime", "trace_t0_s": T0_S, "scenario": {"realtime": {"speed": 0.5}}}, (T0_S, 0.5)),
    ({"mode": "realtime", "trace_t0_s": T0_S, "scenario": {}}, (T0_S, 1.0)),
    ({"trace_t0_s": None}, (0.0, 1.0)),                # a run folder of an earlier release
    ({"mode": "realtime", "scenario": "?"}, (0.0, 1.0)),
])
def test_a_run_folder_gives_its_clock(meta, expected):
    clock = RunClock.of_run(meta)
    assert (clock.t0_s, clock.speed) == expected


def test_lockstep_traces_are_stamped_in_simulated_time():
    assert LOCKSTEP_CLOCK == RunClock() and LOCKSTEP_CLOCK.simulated_s(1.25) == 1.25
    assert LOCKSTEP_CLOCK.trace_s(1_250_000) == 1.25 and LOCKSTEP_CLOCK.simulated_us(1.25) == 1_250_000

"""HIL tests written in pytest with railhil's plugin (hil.pytest_plugin, loaded by installing railhil).

Run them with

    .venv/bin/python -m pytest examples/                      # lockstep: simulated time, deterministic
    .venv/bin/python -m pytest examples/ --junitxml=hil.xml   # JUnit XML for CI, run folders as properties
    .venv/bin/python -m pytest examples/ --hil-mode=realtime  # the same tests on a real python-can bus

`hil_run(scenario, overrides)` runs a scenario (lockstep runs are shared by the tests of a session) and
returns its KPIs, its decoded CAN signals ("MESSAGE.Signal", simulated seconds) and the plant's ground
truth. `within`, `never` and `eventually` check signals over time; a failure names the first violating
time. (tests/cli/test_pytest_plugin.py runs this file as part of `make test`.)
"""

from hil.pytest_plugin import eventually, never, within

DEFAULT = "scenarios/default.toml"      # 6 cars, 90 km/h, full service brake (step 7) at 0.5 s
FULL_SERVICE_MPS2 = 1.0                 # the BCU's target deceleration of brake step 7 [m/s²] (bcu defaults)
STEP_AT_S = 0.5                         # the desk's brake command in default.toml [s]


def test_train_stops_without_losing_a_frame(hil_run):
    run = hil_run(DEFAULT)
    assert run.kpis["stopped"]
    assert run.kpis["frames_lost"] == 0
    assert run.kpis["bus"]["deadline_misses"] == 0
    assert run.report_html.exists()                       # the run's one-page HTML report


def test_bcu_demand_ramps_to_full_service_and_stays_in_range(hil_run):
    run = hil_run(DEFAULT)
    demand = run.signal("BCU_DEMAND.TargetDecel")
    within(demand, 0.0, 0.0, before=STEP_AT_S)            # nothing asked before the driver brakes
    within(demand, 0.0, FULL_SERVICE_MPS2)                # never more than the full service step
    reached = eventually(demand >= 0.99 * FULL_SERVICE_MPS2, after=STEP_AT_S, before=STEP_AT_S + 1.5)
    assert reached > STEP_AT_S                            # a jerk-limited ramp, not a jump


def test_wheel_slide_protection_keeps_slides_short(hil_run):
    run = hil_run(DEFAULT)
    for car in range(1, 7):
        slip = run.truth(f"slip_speed_mps_{car}")         # v − rω of the plant's truth [m/s]
        never(slip > 1.0, for_longer_than=0.5)            # WSP ends every slide within 0.5 s
        never(slip > 3.0)                                 # and none grows beyond 3 m/s


def test_slower_train_stops_sooner(hil_run):
    fast = hil_run(DEFAULT)
    slow = hil_run(DEFAULT, {"train.initial_speed_kmh": 60.0})
    speed = slow.truth("v_mps_1")
    stopped_at = eventually(speed < 0.05, before=fast.kpis["time_to_stop_s"] + STEP_AT_S)
    assert stopped_at < fast.kpis["time_to_stop_s"] + STEP_AT_S
    assert slow.kpis["stopping_distance_m"] < fast.kpis["stopping_distance_m"]

"""The receive table controllers read their inputs from (firmware_py.rx.RxTable)."""

import enum
import math

from firmware_py.rx import RxTable

NAN = math.nan


def test_a_table_reads_nan_and_no_age_until_received():
    rx = RxTable(["AxleSpeed", "TargetDecel"])
    assert math.isnan(rx["AxleSpeed"]) and rx.age_us("AxleSpeed", 1_000) is None
    assert list(rx) == ["AxleSpeed", "TargetDecel"] and rx.get("Other", 7.0) == 7.0


def test_received_values_age_from_their_time_and_a_nan_is_not_received():
    rx = RxTable.received({"AxleSpeed": 30.0, "TargetDecel": NAN}, 20_000)
    assert rx["AxleSpeed"] == 30.0 and rx.age_us("AxleSpeed", 50_000) == 30_000
    assert math.isnan(rx["TargetDecel"]) and rx.age_us("TargetDecel", 50_000) is None


def test_receive_refreshes_values_and_a_nan_forgets_the_reception():
    rx = RxTable.received({"AxleSpeed": 30.0, "TargetDecel": 0.5}, 0)
    version = rx.version
    rx.receive({"AxleSpeed": 29.0, "TargetDecel": NAN}, 10_000)
    assert rx.version > version
    assert rx["AxleSpeed"] == 29.0 and rx.age_us("AxleSpeed", 10_000) == 0
    assert math.isnan(rx["TargetDecel"]) and rx.age_us("TargetDecel", 10_000) is None


def test_update_stores_a_frames_signals_under_their_keys():
    rx = RxTable(["BCU_DEMAND.TargetDecel"])
    rx.update([("TargetDecel", "BCU_DEMAND.TargetDecel")], {"TargetDecel": 0.8, "Mode": 1}, 5_000)
    assert rx["BCU_DEMAND.TargetDecel"] == 0.8 and rx.age_us("BCU_DEMAND.TargetDecel", 8_000) == 3_000


def test_copy_from_takes_values_and_reception_times_from_another_table():
    node = RxTable.received({"RADIO_SIGNAL.Aspect": 2.0, "RADIO_LEADER_INFO.Speed": NAN}, 100_000)
    rx = RxTable.received({"RADIO_LEADER_INFO.Speed": 12.0, "OwnSpeed": 20.0}, 0)
    rx.copy_from(node, ["RADIO_SIGNAL.Aspect", "RADIO_LEADER_INFO.Speed"])
    assert rx["RADIO_SIGNAL.Aspect"] == 2.0 and rx.age_us("RADIO_SIGNAL.Aspect", 150_000) == 50_000
    assert math.isnan(rx["RADIO_LEADER_INFO.Speed"]) and rx.age_us("RADIO_LEADER_INFO.Speed", 150_000) is None
    assert rx["OwnSpeed"] == 20.0 and rx.age_us("OwnSpeed", 150_000) == 150_000


def test_a_copy_is_the_table_as_it_was_and_later_receptions_change_only_one_of_them():
    class Status(enum.Enum):             # stands in for hil.can.e2e.Status
        OK = 0
        WRONGSEQUENCE = 1

    rx = RxTable.received({"AxleSpeed": 30.0, "TargetDecel": 0.5}, 10_000)
    rx.e2e["BCU_DEMAND"] = Status.OK
    snap = rx.copy()
    assert dict(snap) == dict(rx) and snap.version == rx.version and snap.e2e == {"BCU_DEMAND": Status.OK}
    assert snap.age_us("AxleSpeed", 30_000) == 20_000
    rx.receive({"AxleSpeed": 29.0, "TargetDecel": NAN, "Other": 1.0}, 20_000)
    rx.e2e["BCU_DEMAND"] = Status.WRONGSEQUENCE
    assert snap["AxleSpeed"] == 30.0 and snap.age_us("AxleSpeed", 30_000) == 20_000
    assert snap["TargetDecel"] == 0.5 and snap.age_us("TargetDecel", 30_000) == 20_000
    assert "Other" not in snap and snap.version < rx.version and snap.e2e == {"BCU_DEMAND": Status.OK}
    snap.receive({"AxleSpeed": 1.0}, 25_000)
    assert rx["AxleSpeed"] == 29.0 and rx.age_us("AxleSpeed", 30_000) == 10_000

"""Node bindings: every signal name a node uses is checked against the DBC at start."""

import dataclasses
from decimal import Decimal
from fractions import Fraction

import numpy as np
import pytest

from hil.can.codec import Codec
from hil.can.dbc import load_dbc
from hil.errors import BindingError
from hil.runtime.node import Binding, Node, NodeStats

DB = load_dbc()


def build(inputs=("AxleSpeed",), outputs=("ValveCmd",), rx=("PLANT_CAR3_SENSORS",), tx=("BECU3_PRESS_CMD",)):
    return Binding.build(DB, "BECU3", inputs, outputs, rx, tx, "train_brake.dbc")


def test_binding_resolves_bare_and_qualified_names():
    b = build(inputs=("AxleSpeed", "BCU_DEMAND.TargetDecel"))
    fid = DB.get_message_by_name("PLANT_CAR3_SENSORS").frame_id
    assert b.rx[fid] == [("AxleSpeed", "AxleSpeed")]


@pytest.mark.parametrize("kw, needle", [
    ({"inputs": ("AxelSpeed",)}, "'AxelSpeed'"),
    ({"outputs": ("ValveCommand",)}, "'ValveCommand'"),
    ({"inputs": ("PLANT_CAR3_SENSOR.AxleSpeed",)}, "PLANT_CAR3_SENSORS"),
    ({"rx": ("PLANT_CAR3_SENSOR",)}, "PLANT_CAR3_SENSORS"),
])
def test_unknown_names_name_themselves_and_the_closest_dbc_names(kw, needle):
    with pytest.raises(BindingError) as err:
        build(**kw)
    text = str(err.value)
    assert "BECU3" in text and needle in text and "closest" in text and "\n" not in text


def test_closest_name_is_suggested():
    with pytest.raises(BindingError, match="closest: AxleSpeed"):
        build(inputs=("AxelSpeed",))


def test_rx_table_tracks_values_and_ages():
    codec = Codec(DB)
    binding = build(inputs=("AxleSpeed", "BCU_DEMAND.TargetDecel"))
    node = Node("BECU3", None, binding, codec, DB, period_us=10_000)
    assert node.rx["AxleSpeed"] != node.rx["AxleSpeed"]          # NaN until first received
    assert node.rx.age_us("AxleSpeed", 0) is None
    fc = codec.by_name("PLANT_CAR3_SENSORS")
    node.receive(fc.frame_id, fc.encode({"AxleSpeed": 50.0}), 1_000)
    node.receive(fc.frame_id, b"\x01", 2_000)                    # short frame: counted, not raised
    assert node.rx["AxleSpeed"] == 50.0 and node.rx.age_us("AxleSpeed", 11_000) == 10_000
    assert node.stats.bad_frames == 1 and node.stats.frames_received == 1


def test_node_cycle_encodes_due_frames_and_counts_bad_outputs():
    class Ctrl:
        def step(self, now_us, rx):
            return {"ValveCmd": float("nan"), "CylPressureSet": 1e5}

    codec = Codec(DB)
    b = build(outputs=("ValveCmd", "CylPressureSet"))
    node = Node("BECU3", Ctrl(), b, codec, DB, period_us=10_000)
    frames = node.cycle(0)
    assert len(frames) == 1
    fc, data = frames[0]
    values = fc.decode(data)
    assert values["ValveCmd"] == 0.0 and values["CylPressureSet"] == 1e5 and values["COUNTER"] == 0
    assert node.stats.bad_outputs == 1
    assert node.cycle(5_000) == []                         # not due yet
    fc, data = node.cycle(10_000)[0]
    assert fc.decode(data)["COUNTER"] == 1


AWKWARD_OUTPUTS = [
    {"ValveCmd": 0.5, "CylPressureSet": 2e5},                               # all finite: the quick path
    {"ValveCmd": float("nan"), "CylPressureSet": 2e5},
    {"ValveCmd": float("inf"), "CylPressureSet": float("-inf")},            # their sum is NaN
    {"ValveCmd": 1e308, "CylPressureSet": 1e308},                           # finite, their sum is not
    {"ValveCmd": 10 ** 400, "CylPressureSet": 1.0},                          # int + float overflows
    {"ValveCmd": True, "CylPressureSet": 3},                                 # bool and int: finite
    {"ValveCmd": 1j, "CylPressureSet": 0.0},                                 # complex: not a number here
    {"ValveCmd": "0.5", "CylPressureSet": None},
    {"ValveCmd": np.float64("nan"), "CylPressureSet": np.float64(2.0)},
    {"ValveCmd": Decimal("0.5"), "CylPressureSet": Fraction(1, 3)},
    {"ValveCmd": Decimal("NaN"), "CylPressureSet": Decimal("sNaN")},      # sNaN: float() raises
]


@pytest.mark.parametrize("outputs", AWKWARD_OUTPUTS, ids=range(len(AWKWARD_OUTPUTS)))
def test_the_quick_output_check_decides_as_the_check_value_by_value(outputs):
    """Node.cycle takes a step's outputs as they are when one sum of them is a finite int or float, and
    checks them one by one otherwise: both decide alike, on values a controller should never return too."""
    class Ctrl:
        def step(self, now_us, rx):
            return dict(outputs)

    b = build(outputs=("ValveCmd", "CylPressureSet"))
    quick = Node("BECU3", Ctrl(), b, Codec(DB), DB, period_us=10_000)
    quick.cycle(0)
    one_by_one = Node("BECU3", Ctrl(), b, Codec(DB), DB, period_us=10_000)
    one_by_one._check_outputs(outputs)
    assert quick.stats.bad_outputs == one_by_one.stats.bad_outputs
    for key in outputs:
        got, want = quick.outputs[key], one_by_one.outputs[key]
        assert got is want or (got == want and type(got) is type(want)), (key, got, want)


def test_node_stats_as_dict_names_every_counter_in_order():
    """NodeStats.as_dict (a compiled class has no __dict__ for vars()) lists every field, with its value."""
    stats = NodeStats(cycles=3, e2e_status={"OK": 1}, e2e_events=[], last_error="x")
    fields = [f.name for f in dataclasses.fields(NodeStats)]
    assert list(stats.as_dict()) == fields
    assert stats.as_dict() == {name: getattr(stats, name) for name in fields}
    assert stats.as_dict()["e2e_status"] is stats.e2e_status

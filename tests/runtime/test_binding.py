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


NAN = float("nan")
AWKWARD_OUTPUTS = [     # a step's outputs -> what the node keeps of them (None: the safe value, counted)
    ({"ValveCmd": 0.5, "CylPressureSet": 2e5}, {"ValveCmd": 0.5, "CylPressureSet": 2e5}),
    ({"ValveCmd": NAN, "CylPressureSet": 2e5}, {"ValveCmd": None, "CylPressureSet": 2e5}),
    ({"ValveCmd": float("inf"), "CylPressureSet": float("-inf")}, {"ValveCmd": None, "CylPressureSet": None}),
    ({"ValveCmd": 1e308, "CylPressureSet": 1e308}, {"ValveCmd": 1e308, "CylPressureSet": 1e308}),
    ({"ValveCmd": 10 ** 400, "CylPressureSet": 1.0}, {"ValveCmd": 10 ** 400, "CylPressureSet": 1.0}),
    ({"ValveCmd": True, "CylPressureSet": 3}, {"ValveCmd": 1, "CylPressureSet": 3}),      # ints as ints
    ({"ValveCmd": 1j, "CylPressureSet": 0.0}, {"ValveCmd": None, "CylPressureSet": 0.0}),  # complex: none
    ({"ValveCmd": "0.5", "CylPressureSet": None}, {"ValveCmd": None, "CylPressureSet": None}),
    ({"ValveCmd": np.float64("nan"), "CylPressureSet": np.float64(2.0)}, {"ValveCmd": None,
                                                                          "CylPressureSet": 2.0}),
    ({"ValveCmd": Decimal("0.5"), "CylPressureSet": Fraction(1, 3)}, {"ValveCmd": 0.5,    # other numbers:
                                                                      "CylPressureSet": 1 / 3}),   # floats
    ({"ValveCmd": np.int64(7), "CylPressureSet": np.float32(0.5)}, {"ValveCmd": 7.0, "CylPressureSet": 0.5}),
    ({"ValveCmd": Decimal("NaN"), "CylPressureSet": Decimal("sNaN")}, {"ValveCmd": None,     # sNaN: float()
                                                                       "CylPressureSet": None}),   # raises
]


@pytest.mark.parametrize(("outputs", "kept"), AWKWARD_OUTPUTS, ids=range(len(AWKWARD_OUTPUTS)))
def test_a_step_output_that_is_no_finite_number_is_replaced_by_the_safe_value_and_counted(outputs, kept):
    """Node.cycle keeps an int as an int (a bool as 0 or 1, compiled or not) and another finite number as a
    float; NaN, an infinity or a value that is no number is counted (NodeStats.bad_outputs) and replaced by
    the node's safe value."""
    class Ctrl:
        def step(self, now_us, rx):
            return dict(outputs)

    b = build(outputs=("ValveCmd", "CylPressureSet"))
    safe = {"ValveCmd": -1.0, "CylPressureSet": -2.0}
    node = Node("BECU3", Ctrl(), b, Codec(DB), DB, period_us=10_000, safe_outputs=safe)
    node.cycle(0)
    assert node.stats.bad_outputs == sum(v is None for v in kept.values())
    for key, want in kept.items():
        got = node.outputs[key]
        want = safe[key] if want is None else want
        assert got == want and isinstance(got, type(want)) and type(got) is not bool, (key, got, want)


def test_node_stats_as_dict_names_every_counter_in_order_then_the_extra_figures():
    """NodeStats.as_dict (a compiled class has no __dict__ for vars()) lists every field with its value, and
    then a study's extra figures of the node."""
    stats = NodeStats(cycles=3, e2e_status={"OK": 1}, e2e_events=[], last_error="x")
    stats.extra["gps_line"] = {"sentences": 5}
    counters = [f.name for f in dataclasses.fields(NodeStats) if f.name != "extra"]
    assert list(stats.as_dict()) == [*counters, "gps_line"]
    assert stats.as_dict() == {**{name: getattr(stats, name) for name in counters},
                               "gps_line": {"sentences": 5}}
    assert stats.as_dict()["e2e_status"] is stats.e2e_status

"""examples/external_becu, the brake ECU written without railhil, against railhil's own implementation:
the same frame bytes (codec, E2E, SecOC) for the same values and counters, the same verdicts on received
frames, the same control, and in lockstep the same stop; and docs/external-ecu.md against the DBC.

Not real time: the closed loop runs in lockstep, with railhil's BECU3 node replaced frame for frame by the
example's BecuNode (a Node whose receive() and cycle() are the program's); the two runs' frames are the
same, byte for byte.
"""

from __future__ import annotations

import ast
import importlib
import math
import random
import re
import select
import signal
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import can
import cantools
import numpy as np
import pytest

from firmware_py.rx import RxTable
from hil.can import e2e, secoc
from hil.can.attributes import e2e_config, secoc_data_id
from hil.can.codec import Codec
from hil.can.dbc import load_dbc
from hil.runtime.assembly import build_node, node_names
from hil.runtime.node import DEV_SECOC_KEY, Node
from hil.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "external_becu"
DOC = ROOT / "docs" / "external-ecu.md"
DEFAULT = ROOT / "scenarios" / "default.toml"
FEEDBACK = ROOT / "scenarios" / "decel_feedback.toml"    # the BCU sends BCU_BRAKE_CORR, the BECUs take it
CAR = 3
FORBIDDEN = {"hil", "firmware_py", "plant_sim", "railhil"}
ALLOWED_THIRD_PARTY = {"can", "cantools", "cryptography", "numpy"}


@pytest.fixture(scope="module")
def ext():
    """The example's modules, imported from its folder as its program imports them."""
    sys.path.insert(0, str(EXAMPLE))
    try:
        return SimpleNamespace(becu=importlib.import_module("becu"),
                               protection=importlib.import_module("protection"),
                               control=importlib.import_module("brake_control"))
    finally:
        sys.path.remove(str(EXAMPLE))


@pytest.fixture(scope="module")
def rail():
    scenario = load_scenario(DEFAULT)
    db = load_dbc()
    return SimpleNamespace(scenario=scenario, feedback=load_scenario(FEEDBACK), db=db, codec=Codec(db),
                           ext_db=cantools.database.load_file(str(ROOT / "dbc" / "train_brake.dbc")))


def keyed_node(name: str, rail, controller=None, scenario=None):
    """railhil's node `name` of `scenario` (default: the default scenario), keyed as a run keys it, its
    controller replaced."""
    scenario = scenario or rail.scenario
    node = build_node(name, scenario, rail.db, rail.codec)
    node.use_keys({}, scenario.secoc.window)
    if controller is not None:
        node.controller = controller
    return node


class Script:
    """A controller that returns the outputs it is given, one dict per cycle."""

    def __init__(self, outputs: list[dict]) -> None:
        self.outputs = iter(outputs)

    def step(self, now_us, rx):
        return next(self.outputs)


def becu_outputs(rng: random.Random) -> dict:
    """Values of every BECU output, inside and beyond their DBC ranges (the codec saturates)."""
    return {"CylPressureSet": rng.uniform(-1e4, 6e5), "ValveCmd": rng.uniform(-1.2, 1.2),
            "WspValve": rng.choice((0, 1, 2)), "SpeedEst": rng.uniform(0, 30),
            "SlipSpeedEst": rng.uniform(-3, 3),
            "WspActive": rng.choice((0, 1)), "GovernorActive": 0, "IntegratorSat": rng.choice((0, 1)),
            "InputMissing": rng.choice((0, 1)), "OptSlipEst": 0.0, "OptSlipPos": 0.0,
            "GovernedDecel": rng.uniform(0, 1.3), "GovernorMargin": rng.uniform(-7e4, 7e4),
            "GovernorFeasible": 1, "SpeedSensorFault": 0, "AccelSensorFault": 0,
            "CylSensorFault": rng.choice((0, 1)), "AccelBiasEst": rng.uniform(-5, 5)}


# --- (1) the bytes on the wire -------------------------------------------------------------------------

def test_the_frames_the_example_sends_are_railhils_byte_for_byte(ext, rail):
    rng = random.Random(7)
    outputs = [becu_outputs(rng) for _ in range(40)]
    node = keyed_node(f"BECU{CAR}", rail, Script(outputs))
    senders = {name: ext.protection.Sender(rail.ext_db.get_message_by_name(name), DEV_SECOC_KEY)
               for name in ext.becu.becu_frames(CAR)[1]}
    compared = {}
    for k, out in enumerate(outputs):        # 40 cycles: the E2E counter wraps (0..14) twice
        for fc, data in node.cycle(node.offset_us + 10_000 * k):
            assert senders[fc.name].frame(out) == data, (fc.name, k)
            compared[fc.name] = compared.get(fc.name, 0) + 1
    # every frame of both, at the DBC's cycle times: PRESS_CMD 10 ms, STATUS and DIAG 50 ms, EST 100 ms
    assert compared == {name: 400 // int(rail.db.get_message_by_name(name).cycle_time) for name in senders}
    assert compared[f"BECU{CAR}_PRESS_CMD"] == 40


def bcu_outputs(rng: random.Random, k: int) -> dict:
    return {"Mode": 1, "BrakeStep": 7, "TargetDecel": min(k * 0.01, 1.0) + rng.uniform(0, 0.004),
            "EmergencyActive": int(k % 9 == 4), "Source": 1, "CarsSilent": 0, "Degraded": 0,
            "TrainSpeedEst": 25.0 - 0.01 * k, "CarsImplausible": 0, "FbState": k // 10 % 4,
            "FrictionPhi": rng.uniform(0.7, 1.4), "SlopeEst": 0.0, "StopState": 0}


@pytest.mark.parametrize(("scenario", "taken_expected", "rejects"), [
    # 50 sensor frames, 50 demands and 25 emergency frames less the two INITIAL ones
    ("scenario", 50 + 49 + 24, (2, 0)),
    # and 5 BCU_BRAKE_CORR (FbState OFF, MONITOR, ENGAGED, HELD, OFF) less the INITIAL one
    ("feedback", 50 + 49 + 24 + 4, (3, 0)),
])
def test_railhil_frames_are_taken_by_the_example_as_railhils_becu_takes_them(ext, rail, scenario,
                                                                               taken_expected, rejects):
    rng = random.Random(3)
    scenario = getattr(rail, scenario)
    bcu = keyed_node("BCU", rail, Script([bcu_outputs(rng, k) for k in range(100)]), scenario)
    plant = keyed_node("PLANT", rail, scenario=scenario)      # the real plant: its sensors, its counters
    theirs = keyed_node(f"BECU{CAR}", rail, scenario=scenario)
    ours = ext.becu.BecuNode(rail.ext_db, CAR, start_us=theirs.offset_us)
    inputs = {"axle_speed_rad_s": "AxleSpeed", "cyl_pressure_Pa": "CylPressure",
              "accel_mps2": "AccelLong", "target_decel_mps2": "TargetDecel", "emergency": "EmergencyActive",
              "friction_phi": "FrictionPhi", "fb_state": "FbState"}
    taken = 0
    for t in range(0, 500_000, 1_000):
        frames = plant.cycle(t) + (bcu.cycle(t) if t % 10_000 == bcu.offset_us else [])
        for fc, data in frames:
            if fc.frame_id not in theirs.rx_ids:
                continue
            theirs.receive(fc.frame_id, data, t)
            taken += ours.receive(fc.frame_id, data, t)
            for key, name in inputs.items():          # a signal railhil's BECU does not bind: NaN in both
                mine, rails = ours.values.get(key, math.nan), theirs.rx.get(name, math.nan)
                assert mine == rails or (math.isnan(mine) and math.isnan(rails)), (fc.name, t, name)
            if fc.name in theirs.rx.e2e:
                _, receiver = ours.receivers[fc.frame_id]
                assert receiver.last.value == theirs.rx.e2e[fc.name].value, (fc.name, t)
        if t % 10_000 == theirs.offset_us:                   # the E2E checks of cycles without a frame
            theirs.cycle(t)
            ours.cycle(t)
            assert ours.inputs(t).demand_age_us == theirs.rx.age_us("TargetDecel", t)
            assert ours.inputs(t).phi_age_us == theirs.rx.age_us("FrictionPhi", t)       # φ's timeout
            assert ours.inputs(t).sensors_age_us == theirs.rx.age_us("AxleSpeed", t)     # a new reading?
    assert taken == taken_expected
    assert ours.rejects() == rejects
    feedback = scenario is rail.feedback                 # φ and FbState only from a BCU with the feedback
    assert ("friction_phi" in ours.values, "fb_state" in ours.values) == (feedback, feedback)


def test_railhils_plant_and_bcu_take_the_examples_authenticated_frames(ext, rail):
    plant, bcu = keyed_node("PLANT", rail), keyed_node("BCU", rail)
    ours = ext.becu.BecuNode(rail.ext_db, CAR, start_us=0)
    cmd = rail.db.get_message_by_name(f"BECU{CAR}_PRESS_CMD").frame_id
    status = rail.db.get_message_by_name(f"BECU{CAR}_STATUS").frame_id
    assert ours.receive(rail.db.get_message_by_name(f"PLANT_CAR{CAR}_SENSORS").frame_id, bytes(8), 0)
    for k in range(30):                                     # the train is heard: everything from cycle 0
        for frame_id, data in ours.cycle(10_000 * k):
            sent = rail.codec[frame_id].decode(data)
            if frame_id == cmd:
                plant.receive(frame_id, data, 10_000 * k + 300)
                assert plant.rx[f"BECU{CAR}_PRESS_CMD.ValveCmd"] == sent["ValveCmd"] or k == 0
            elif frame_id == status:
                bcu.receive(frame_id, data, 10_000 * k + 300)
                assert bcu.rx[f"BECU{CAR}_STATUS.SpeedEst"] == sent["SpeedEst"] or k == 0
    assert plant.stats.secoc_rejected == {} and bcu.stats.secoc_rejected == {}
    assert plant.stats.e2e_status == {"INITIAL": 1, "OK": 29}
    assert bcu.stats.e2e_status == {"INITIAL": 1, "OK": 5}


def test_the_authenticated_frames_wait_for_the_train_the_others_do_not(ext, rail):
    ours = ext.becu.BecuNode(rail.ext_db, CAR, start_us=0)
    names = {rail.db.get_message_by_name(n).frame_id: n for n in ext.becu.becu_frames(CAR)[1]}
    authenticated = {n for n in names.values() if secoc_data_id(rail.db.get_message_by_name(n))}
    assert authenticated == {f"BECU{CAR}_PRESS_CMD", f"BECU{CAR}_STATUS"}
    sent = [names[fid] for k in range(10) for fid, _ in ours.cycle(10_000 * k)]      # 100 ms, no train
    assert sorted(sent) == sorted(n for n in names.values() if n not in authenticated
                                  for _ in range(100 // int(rail.db.get_message_by_name(n).cycle_time)))
    assert set(sent) == {f"BECU{CAR}_DIAG", f"BECU{CAR}_EST"}
    ours.receive(rail.db.get_message_by_name("BCU_DEMAND").frame_id, bytes(8), 100_000)   # rejected, heard
    first = {}
    for k in range(10, 20):
        for fid, data in ours.cycle(10_000 * k):
            first.setdefault(names[fid], data)
    assert set(first) == set(names.values())
    for name in authenticated:                             # freshness 1: the receivers' window holds it
        assert rail.codec.by_name(name).decode(first[name])["SecOCFreshness"] == 1, name


# --- (2) E2E and SecOC: the same verdicts as railhil's, rejections -------------------------------------

def e2e_pairs(ext, rail):
    """(railhil's config, the example's) for BCU_DEMAND (P01 behind SecOC) and a profile 2 frame."""
    msg = rail.db.get_message_by_name("BCU_DEMAND")
    ids = tuple(random.Random(5).randrange(256) for _ in range(16))
    return [(e2e_config(msg), ext.protection.e2e_config(rail.ext_db.get_message_by_name("BCU_DEMAND"))),
            (e2e.P02Config(ids, length=8), ext.protection.E2EConfig("P02", 8, data_id_list=ids))]


def test_e2e_protect_and_check_agree_with_railhil_on_a_random_stream(ext, rail):
    prot = ext.protection
    for theirs_cfg, our_cfg in e2e_pairs(ext, rail):
        rng = random.Random(11)
        sender, counter = e2e.ProtectState(), 0
        theirs_state, our_state = e2e.CheckState(), prot.CheckState()
        statuses = set()
        last = None
        for _ in range(3000):
            payload = bytes(rng.randrange(256) for _ in range(our_cfg.length))
            theirs = e2e.protect(theirs_cfg, sender, payload)
            mine, counter = prot.e2e_protect(our_cfg, counter, payload)
            assert mine == theirs
            event = rng.random()
            if event < 0.15:
                frame = None                                  # lost: the cycle without a frame
            elif event < 0.25 and last is not None:
                frame = last                                  # repeated
            elif event < 0.35:
                frame = bytes([theirs[0] ^ 1 << rng.randrange(8)]) + theirs[1:]   # corrupted
            elif event < 0.40:
                frame = theirs[:1] + bytes([theirs[1] ^ 0x0F]) + theirs[2:]          # counter wrong
            else:
                frame = theirs
            last = theirs
            theirs_state, status = e2e.check(theirs_cfg, theirs_state, frame)
            our_state, our_status = prot.e2e_check(our_cfg, our_state, frame)
            assert our_status.value == status.value
            assert (our_status in prot.USABLE) == status.usable
            statuses.add(status.value)
        assert {"OK", "OKSOMELOST", "REPEATED", "ERROR", "NONEWDATA"} <= statuses


def test_secoc_agrees_with_railhil(ext):
    prot = ext.protection
    rng = random.Random(13)
    key = bytes(rng.randrange(256) for _ in range(16))
    for _ in range(200):
        data_id, fresh = rng.randrange(1 << 16), rng.randrange(1 << 40)
        payload = bytes(rng.randrange(256) for _ in range(4))
        theirs = secoc.authenticate(key, data_id, fresh, payload)
        assert prot.authenticator(key, data_id, fresh, payload) == theirs
        last, received = rng.randrange(1 << 40), rng.randrange(256)
        assert prot.rebuild_freshness(last, received) == secoc.rebuild_freshness(last, received)


def demand_stream(rail, n: int, key: bytes = DEV_SECOC_KEY) -> list[bytes]:
    """`n` BCU_DEMAND frames as railhil's BCU sends them."""
    bcu = build_node("BCU", rail.scenario, rail.db, rail.codec)
    bcu.use_keys({"*": key})
    bcu.controller = Script([bcu_outputs(random.Random(1), k) for k in range(n)])
    out = []
    for k in range(n):
        out += [data for fc, data in bcu.cycle(2_000 + 10_000 * k) if fc.name == "BCU_DEMAND"]
    return out


def resecure(rail, authentic: bytes, freshness: int) -> bytes:
    """A BCU_DEMAND frame with a valid MAC over `authentic` (what a sender with the key could send)."""
    return authentic + secoc.authenticate(DEV_SECOC_KEY, 0x028, freshness, authentic)


def test_the_example_rejects_a_bad_crc_a_wrong_mac_a_repeated_counter_and_a_replay(ext, rail):
    prot = ext.protection
    msg = rail.ext_db.get_message_by_name("BCU_DEMAND")
    frames = demand_stream(rail, 6)

    def receiver_after_two():
        rx = prot.Receiver(msg, DEV_SECOC_KEY)
        assert rx.receive(frames[0], 0) is None and rx.last is prot.Status.INITIAL
        assert rx.receive(frames[1], 10_000) is not None and rx.last is prot.Status.OK
        return rx

    rx = receiver_after_two()                      # a bad CRC behind a valid MAC: E2E says ERROR
    bad_crc = bytes([frames[2][0] ^ 0x10]) + frames[2][1:4]
    assert rx.receive(resecure(rail, bad_crc, 3), 20_000) is None and rx.last is prot.Status.ERROR
    assert rx.receive(frames[3], 30_000) is not None                   # the stream goes on

    rx = receiver_after_two()                      # a wrong MAC
    forged = frames[2][:7] + bytes([frames[2][7] ^ 0x01])
    assert rx.receive(forged, 20_000) is None and rx.last is prot.SecOcVerdict.MAC
    other_key = demand_stream(rail, 3, key=bytes(16))[2]             # the right frame, another key
    assert rx.receive(other_key, 20_000) is None and rx.last is prot.SecOcVerdict.MAC
    assert rx.receive(frames[2], 20_000) is not None

    rx = receiver_after_two()                      # the same E2E counter again, freshly authenticated
    assert rx.receive(resecure(rail, frames[1][:4], 3), 20_000) is None
    assert rx.last is prot.Status.REPEATED

    rx = receiver_after_two()                      # the last frame replayed as it was recorded
    assert rx.receive(frames[1], 20_000) is None and rx.last is prot.SecOcVerdict.STALE
    assert (rx.e2e_rejects, rx.secoc_rejects) == (1, 1)              # INITIAL, then the replay


def test_a_rejected_demand_ages_into_loss_of_command(ext, rail):
    node = ext.becu.BecuNode(rail.ext_db, CAR, start_us=0)
    fid = rail.db.get_message_by_name("BCU_DEMAND").frame_id
    frames = demand_stream(rail, 8)
    for k in range(3):
        node.receive(fid, frames[k], 10_000 * k)
    for k in range(3, 8):                         # every later demand forged: not taken, the demand ages
        assert not node.receive(fid, frames[k][:7] + b"\x00", 10_000 * k)
    assert node.inputs(80_000).demand_age_us == 60_000
    out = node.control.step(80_000, node.inputs(80_000))
    assert out["InputMissing"] == 1 and out["CylPressureSet"] == pytest.approx(329_000.0)


# --- the control against railhil's BECU ----------------------------------------------------------------

def railhil_becu():
    """railhil's BECU as the bench fits it in a train with deceleration feedback and no governor (the
    stages hil/studies/*/nodes.py fit): the governor's signals filled as the DBC defines them, φ applied."""
    from firmware_py.becu import Becu, BecuParams
    from firmware_py.decel_feedback import PhiCorrection, PhiParams
    from firmware_py.governor import Ungoverned

    p = BecuParams()
    return Becu(p, [Ungoverned()], [PhiCorrection(PhiParams(), p.brake_preload_Pa, p.p_max_Pa)])


def test_the_control_steps_as_railhils_becu(ext):
    theirs, ours = railhil_becu(), ext.control.BrakeControl()
    rx = RxTable(theirs.inputs)                    # a train with deceleration feedback
    r, v, p = 0.46, 25.0, 0.0
    t_demand = None
    corrected = set()                              # FbState values under which φ changed the set-point
    for k in range(1500):                          # 15 s: ramp, slides, a lost demand, emergency
        t = 3_000 + 10_000 * k
        slip = 1.5 * max(0.0, math.sin(k / 40.0)) ** 8 if 200 < k < 900 else 0.0
        accel = -0.9 if v > 0 else 0.0
        v = max(v + accel * 0.01, 0.0)
        demand = min(k * 0.01, 1.0)
        sensors = {"AxleSpeed": max(v - slip, 0.0) / r, "CylPressure": p, "AccelLong": accel}
        rx.update([(n, n) for n in sensors], sensors, t - 2_000)
        if not 1000 <= k < 1010:                    # 100 ms without a usable demand
            t_demand = t - 1_000
            rx.update([("TargetDecel", "TargetDecel"), ("EmergencyActive", "EmergencyActive")],
                      {"TargetDecel": demand, "EmergencyActive": float(1200 <= k < 1250)}, t_demand)
        if k % 10 == 0:                             # BCU_BRAKE_CORR, 100 ms: the four FbStates in turn,
            rx.update([("FrictionPhi", "FrictionPhi"), ("FbState", "FbState")],      # ENGAGED over the
                      {"FrictionPhi": 1.1 + 0.05 * math.sin(k / 100.0),              # lost demand and
                       "FbState": float((k // 60 + 2) % 4)}, t - 1_500)              # the emergency
        want = theirs.step(t, rx)
        got = ours.step(t, ext.control.Inputs(
            axle_speed_rad_s=rx["AxleSpeed"], cyl_pressure_Pa=p, accel_mps2=accel,
            target_decel_mps2=rx["TargetDecel"], emergency=rx["EmergencyActive"],
            friction_phi=rx["FrictionPhi"], fb_state=rx["FbState"], demand_age_us=t - t_demand))
        for key, value in want.items():
            if key != "AccelBiasEst":
                assert got[key] == pytest.approx(value, abs=1e-9), (k, key)
        if want["CylPressureSet"] != theirs.pressure_for_decel(want["GovernedDecel"]):
            corrected.add(rx["FbState"])
        # the cylinder as the plant's valves move it (docs/external-ecu.md): the EP valve fills at 1 MPa/s
        # and vents at 1.5 MPa/s at full opening, the dump valve holds (HOLD) or vents at 2 MPa/s (VENT)
        valve, dump = want["ValveCmd"], want["WspValve"]
        rate = 0.0 if dump == 1 else -2e6 if dump == 2 else valve * (1e6 if valve > 0 else 1.5e6)
        p = min(max(p + rate * 0.01, 0.0), 450e3)
    assert theirs.failsafe_cycles == ours.lost_cycles > 0
    assert corrected == {2.0, 3.0}                 # φ applied while ENGAGED and HELD, never OFF or MONITOR


@pytest.mark.parametrize("fault", ["none", "wheel held down 2 s", "cylinder pressure stuck",
                                   "cylinder pressure reads 0", "wheel speed frozen", "wheel stands",
                                   "accelerometer biased"])
def test_the_control_steps_as_railhils_becu_through_sensor_faults_and_lost_frames(ext, fault):
    """As above, with what that test does not exercise: sensor frames that do not come every cycle, a
    BCU_BRAKE_CORR that stops for longer than φ's 300 ms timeout, and, from 7 s on, a failing sensor (with
    an emergency brake that moves the valves while it has failed); the ages passed as BecuNode passes
    them, every output compared, AccelBiasEst too."""
    theirs, ours = railhil_becu(), ext.control.BrakeControl()
    rx = RxTable(theirs.inputs)
    r, v, p = 0.46, 25.0, 0.0
    held = {}                                      # the stuck readings
    applied = []                                   # φ changed the set-point, per cycle
    for k in range(1200):                          # 12 s
        t = 3_000 + 10_000 * k
        slip = 1.5 * max(0.0, math.sin(k / 40.0)) ** 8 if 200 < k < 600 else 0.0
        accel = -0.9 if v > 0 else 0.0
        v = max(v + accel * 0.01, 0.0)
        sensors = {"AxleSpeed": max(v - slip, 0.0) / r, "CylPressure": p, "AccelLong": accel}
        if k >= 700:                               # the sensor fails
            if fault == "wheel held down 2 s" and k < 900:      # a slide deeper than WSP brings back
                sensors["AxleSpeed"] *= 0.4
            elif fault == "cylinder pressure stuck":
                sensors["CylPressure"] = held.setdefault("p", p)
            elif fault == "cylinder pressure reads 0":       # it jumps there: the model starts before it
                sensors["CylPressure"] = 0.0
            elif fault == "wheel speed frozen":
                sensors["AxleSpeed"] = held.setdefault("w", sensors["AxleSpeed"])
            elif fault == "wheel stands":
                sensors["AxleSpeed"] = 0.0
            elif fault == "accelerometer biased":
                sensors["AccelLong"] = accel + 2.0   # a slide the wheel then ends by spinning up
        if k % 7 != 3:                             # every 7th sensor frame lost: no new reading that cycle
            rx.update([(n, n) for n in sensors], sensors, t - 2_000)
        rx.update([("TargetDecel", "TargetDecel"), ("EmergencyActive", "EmergencyActive")],
                  {"TargetDecel": min(k * 0.01, 1.0), "EmergencyActive": float(800 <= k < 900)}, t - 1_000)
        if k % 10 == 0 and not 400 <= k < 460:     # BCU_BRAKE_CORR ENGAGED, silent for 600 ms from k = 400
            rx.update([("FrictionPhi", "FrictionPhi"), ("FbState", "FbState")],
                      {"FrictionPhi": 1.2, "FbState": 2.0}, t - 1_500)
        want = theirs.step(t, rx)
        got = ours.step(t, ext.control.Inputs(
            axle_speed_rad_s=rx["AxleSpeed"], cyl_pressure_Pa=rx["CylPressure"], accel_mps2=rx["AccelLong"],
            target_decel_mps2=rx["TargetDecel"], emergency=rx["EmergencyActive"],
            friction_phi=rx["FrictionPhi"], fb_state=rx["FbState"],
            demand_age_us=rx.age_us("TargetDecel", t), phi_age_us=rx.age_us("FrictionPhi", t),
            sensors_age_us=rx.age_us("AxleSpeed", t)))
        extra = set(got) - set(want)               # preview slip control's, which the example sends as
        assert set(want) <= set(got) and extra == {"OptSlipEst", "OptSlipPos"}    # zeros: railhil's BECU
        assert all(got[key] == 0.0 for key in extra)                             # without that study none
        for key, value in want.items():
            assert got[key] == pytest.approx(value, abs=1e-9), (k, key)
        applied.append(want["CylPressureSet"] != theirs.pressure_for_decel(want["GovernedDecel"]))
        valve, dump = want["ValveCmd"], want["WspValve"]
        rate = 0.0 if dump == 1 else -2e6 if dump == 2 else valve * (1e6 if valve > 0 else 1.5e6)
        p = min(max(p + rate * 0.01, 0.0), 450e3)
    # the last BCU_BRAKE_CORR came at k = 390: φ applied up to 300 ms after it, not from k = 420 until the
    # frames return at k = 460
    assert all(applied[390:420]) and not any(applied[420:460]) and applied[460]
    flags = {"cylinder pressure stuck": "CylSensorFault", "cylinder pressure reads 0": "CylSensorFault",
             "wheel speed frozen": "SpeedSensorFault", "wheel stands": "SpeedSensorFault",
             "accelerometer biased": "AccelSensorFault"}
    if fault in flags or fault == "none":           # the failing sensor is found (and only that one)
        assert {f for f in ("CylSensorFault", "SpeedSensorFault", "AccelSensorFault") if got[f]} == (
            {flags[fault]} if fault in flags else set())


# --- the closed loop in lockstep -----------------------------------------------------------------------

def stopping_distance(outcome, t_brake_s: float, n_cars: int) -> float:
    cols = outcome.truth.columns()
    t = cols["t_s"]
    v = np.column_stack([cols[f"v_mps_{k}"] for k in range(1, n_cars + 1)])
    stop = np.flatnonzero(np.all(v < 0.01, axis=1) & (t >= t_brake_s))
    assert stop.size, "the train did not stop"
    return float(cols["x_m_1"][stop[0]] - np.interp(t_brake_s, t, cols["x_m_1"]))


class Frames(can.Listener):
    """Every frame of a run, in bus order: (time [s], frame id, data)."""

    def __init__(self) -> None:
        self.frames: list[tuple[float, int, bytes]] = []

    def on_message_received(self, msg: can.Message) -> None:
        self.frames.append((msg.timestamp, msg.arbitration_id, bytes(msg.data)))


class ExampleBecuNode(Node):
    """railhil's node of BECU{CAR} whose frames are the example program's: what the bus brings it goes to the
    program's receive(), and its cycles send what the program's cycle() returns."""

    def __init__(self, node: Node, program, codec: Codec, db) -> None:
        super().__init__(node.name, node.controller, node.binding, codec, db, node.period_us, node.offset_us)
        self.program = program

    def receive(self, frame_id: int, data: bytes, t_us: int) -> None:
        self.program.receive(frame_id, data, t_us)

    def cycle(self, now_us: int, nominal_us: int | None = None) -> list:
        frames = self.program.cycle(now_us)
        self.stats.frames_sent += len(frames)
        return [(self.codec[fid], data) for fid, data in frames]


def run_train(rail, scenario, ext=None, writer=None):
    """A lockstep run of `scenario`: (setup, outcome, the example's BecuNode as BECU3 or None); `writer`
    gets every frame."""
    from hil.runtime.lockstep import prepare_lockstep, run_lockstep

    setup = prepare_lockstep(scenario, rail.db, rail.codec)
    k = next(k for k, n in enumerate(setup.nodes) if n.name == f"BECU{CAR}")
    ours = None
    if ext is not None:                            # railhil's BECU3, frame for frame the example's
        node = setup.nodes[k]
        ours = ext.becu.BecuNode(rail.ext_db, CAR, window=scenario.secoc.window, start_us=node.offset_us)
        setup.nodes[k] = ExampleBecuNode(node, ours, rail.codec, rail.db)
    return setup, run_lockstep(scenario, rail.db, rail.codec, writer, setup=setup), ours


@pytest.mark.parametrize(("scenario", "rejects"), [
    ("scenario", (2, 0)),                          # the default train: the INITIAL demand and emergency
    ("feedback", (3, 0)),                          # and the INITIAL BCU_BRAKE_CORR; φ engaged in the stop
])
def test_the_train_stops_as_far_with_the_example_as_becu3(ext, rail, scenario, rejects):
    scenario = getattr(rail, scenario)
    t_brake = scenario.desk[0].at_s
    n = scenario.train.cars
    theirs_frames, our_frames = Frames(), Frames()
    _, reference, _ = run_train(rail, scenario, writer=theirs_frames)
    setup, outcome, becu = run_train(rail, scenario, ext, writer=our_frames)
    assert outcome.reason == "standstill"
    ours, theirs = stopping_distance(outcome, t_brake, n), stopping_distance(reference, t_brake, n)
    assert ours == pytest.approx(theirs, rel=0.02)
    for name, message in (("PLANT", f"BECU{CAR}_PRESS_CMD"), ("BCU", f"BECU{CAR}_STATUS")):
        stats = outcome.node_stats[name]
        assert not stats["secoc_rejected"], name
        assert [e[2] for e in stats["e2e_events"] if e[1] == message] == ["INITIAL"], name
    bcu = next(n for n in setup.nodes if n.name == "BCU").controller
    assert not bcu.implausible[CAR - 1]
    assert becu.rejects() == rejects
    # the example's control is railhil's BECU step for step: the two runs are the same, frame for frame
    mine, rails = our_frames.frames, theirs_frames.frames
    first = next((k for k, (a, b) in enumerate(zip(mine, rails, strict=False)) if a != b), None)
    assert first is None, (rail.db.get_message_by_frame_id(mine[first][1]).name, mine[first], rails[first])
    assert len(mine) == len(rails) > 0


# --- (3) the example is not railhil --------------------------------------------------------------------

def test_the_example_imports_nothing_of_railhil():
    files = sorted(EXAMPLE.glob("*.py"))
    local = {f.stem for f in files}
    assert {"becu", "protection", "brake_control"} <= local
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                assert node.level == 0, f"{path.name}: relative import"
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                assert top not in FORBIDDEN, f"{path.name} imports {name}"
                assert top in sys.stdlib_module_names | ALLOWED_THIRD_PARTY | local, f"{path.name}: {name}"


# --- the program ---------------------------------------------------------------------------------------

def read_line(proc, timeout_s: float = 20.0) -> str:
    ready, _, _ = select.select([proc.stdout], [], [], timeout_s)
    assert ready, "no line from the example within the timeout"
    return proc.stdout.readline()


SUMMARY = (rf"external BECU{CAR}: (\d+) cycles, (\d+) frames sent, 0 received, 0 E2E rejects, "
           r"0 SecOC rejects, \d+ late, \d+ skipped")


def example(*args: str) -> list[str]:
    return [sys.executable, str(EXAMPLE / "becu.py"), "--car", str(CAR), *args]


def test_the_program_says_where_it_is_and_ends_cleanly_on_sigterm():
    proc = subprocess.Popen(example("-i", "virtual", "-c", "external-becu-test"), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        line = read_line(proc)
        assert line.strip() == (f"external BECU{CAR}: on virtual external-becu-test, sending "
                                f"BECU{CAR}_PRESS_CMD, BECU{CAR}_STATUS, BECU{CAR}_DIAG, BECU{CAR}_EST")
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=10)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert re.fullmatch(SUMMARY, out.strip()), out


def test_the_program_runs_its_cycle_for_the_duration_asked():
    proc = subprocess.run(example("-i", "virtual", "--duration", "0.3"), capture_output=True, text=True,
                          timeout=30)
    assert proc.returncode == 0, proc.stderr
    summary = re.fullmatch(SUMMARY, proc.stdout.strip().splitlines()[-1])
    assert summary, proc.stdout
    cycles, sent = int(summary[1]), int(summary[2])
    assert 0 < cycles <= 31                    # 10 ms cycles for 0.3 s (fewer on a stalled machine)
    assert 0 < sent <= 7 + 4                   # DIAG every 50 ms, EST every 100 ms; no train heard: no
    #                                            PRESS_CMD and no STATUS (authenticated)


def test_a_bus_that_does_not_open_is_one_line_and_exit_2():
    proc = subprocess.run(example("-i", "socketcan", "-c", "nosuchcan9"), capture_output=True, text=True,
                          timeout=30)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: cannot open the bus"), proc.stderr
    assert proc.stdout == ""


# --- (4) the wire contract's table against the DBC -----------------------------------------------------

def doc_table(header_start: str) -> list[list[str]]:
    lines = DOC.read_text(encoding="utf-8").splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(header_start))
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        rows.append([c.strip() for c in line.strip("|").split("|")])
    return rows


def cell(text: str, n: int) -> int | None:
    """`0x030 + n`, `0x028`, `40` or `—` for car `n`."""
    if text == "—":
        return None
    m = re.fullmatch(r"(0x[0-9A-Fa-f]+|\d+)( \+ n)?", text)
    assert m, f"docs/external-ecu.md: cannot read {text!r}"
    return int(m[1], 0) + (n if m[2] else 0)


def test_the_frame_table_of_the_wire_contract_matches_the_dbc(ext, rail):
    rows = doc_table("| frame | id |")
    documented = set()
    for name_cell, id_cell, length, cycle, sender, _, profile, data_id, secoc_id in rows:
        template = name_cell.strip("`")
        for n in (range(1, 9) if "n" in id_cell else (0,)):
            name = template.replace("BECUn", f"BECU{n}").replace("CARn", f"CAR{n}")
            msg = rail.db.get_message_by_name(name)
            where = f"docs/external-ecu.md, {name}"
            assert msg.frame_id == cell(id_cell, n), where
            assert msg.length == int(length), where
            assert msg.cycle_time == int(cycle), where
            assert msg.senders == [sender.replace("BECUn", f"BECU{n}")], where
            cfg = e2e_config(msg)
            assert (cfg is None) == (profile == "—"), where
            if cfg is not None:
                assert profile == "P01" and isinstance(cfg, e2e.P01Config), where
                assert cfg.data_id == cell(data_id, n), where
                assert cfg.length == (4 if secoc_data_id(msg) else msg.length), where
            assert secoc_data_id(msg) == cell(secoc_id, n), where
            documented.add(name)
    # every frame the foundation's nodes of the default train, and of a train with deceleration feedback
    # (BCU_BRAKE_CORR), send or receive is in the table, and every frame the example sends or receives
    used = set()
    for scenario in (rail.scenario, rail.feedback):
        for name in node_names(scenario):
            node = build_node(name, scenario, rail.db, rail.codec)
            used |= {tx.codec.name for tx in node.tx}
            used |= {rail.db.get_message_by_frame_id(f).name for f in node.rx_ids}
    used.add("DESK_TARGET")                       # sent by DESK, read by the BCU with precise stopping
    assert used <= documented
    for n in range(1, 9):
        rx, tx = ext.becu.becu_frames(n)
        assert set(rx + tx) <= documented, n
    protected = {m.name for m in rail.db.messages if e2e_config(m) or secoc_data_id(m)}
    assert protected - documented == {"ACD_BRAKE_REQ"}      # a study's frame (anticollision)


def test_the_worked_example_of_the_wire_contract_is_what_railhil_and_the_example_send(ext, rail):
    text = DOC.read_text(encoding="utf-8")

    def hex_line(label: str) -> bytes:
        m = re.search(rf"^{label} +((?:[0-9a-f]{{2}} ?)+)", text, re.MULTILINE)
        assert m, f"docs/external-ecu.md: no line {label!r} in the worked example"
        return bytes.fromhex(m[1])

    values = {"CylPressureSet": 329000, "ValveCmd": 0.5, "WspValve": 0}
    name = "BECU3_PRESS_CMD"
    msg = rail.db.get_message_by_name(name)
    encoded = rail.codec.by_name(name).encode(values)
    protected = e2e.protect(e2e_config(msg), e2e.ProtectState(), encoded[:4])
    frame = secoc.SecOcSender(DEV_SECOC_KEY, secoc_data_id(msg)).secure(protected)
    assert hex_line("encoded") == encoded
    assert hex_line("E2E") == protected
    assert hex_line("MAC over") == secoc.data_to_authenticate(secoc_data_id(msg), 1, protected)
    assert hex_line("frame") == frame
    assert ext.protection.Sender(rail.ext_db.get_message_by_name(name), DEV_SECOC_KEY).frame(values) == frame

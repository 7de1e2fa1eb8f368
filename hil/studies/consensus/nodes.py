"""The nodes of consensus braking (seed 003), for a scenario with a [consensus] section.

`node_names` gets the foundation's node list (PLANT first) and returns this study's: PLANT (the
seed-003 plant, plant_sim/consensus.py), BCU (the virtual leader of eq. (9)) and BECU1..n (the consensus
law, firmware_py/consensus.py).  The desk and the foundation's pneumatic brake are not part of the
paper's model.  `build_node` builds them all.

Schedule inside one consensus cycle T (the DBC cycle of the BECUn_CONS and PLANT_CONS_CARn frames): the
plant sends the n sensor frames at the start of the cycle; BECU i runs once its sensor frame has
arrived, the BECU frames overtaking the sensor frames still queued (their identifiers are lower):
offset_i = i·t_S + (i − 1)·t_C + 20 µs, with t_S, t_C the frames' worst-case durations at the bus bitrate
(becu_offset_us).  The BCU sends CONS_REF after the loop's frames (bcu_offset_us), so that it never
delays a sensor frame.
"""

from __future__ import annotations

import math

import numpy as np
from cantools.database.can import Database

from firmware_py.consensus import (
    KMH,
    POSITION_WRAP_M,
    SAMPLE_MODULO,
    ConsensusBecu,
    VirtualLeader,
    VirtualLeaderParams,
)
from hil.can.busload import declared_bitrate, frame_bits
from hil.can.codec import Codec
from hil.errors import BindingError
from hil.runtime.node import Binding, Node
from hil.scenario import Scenario
from hil.studies.consensus.scenario import consensus_becu_params, consensus_plant_params
from plant_sim.consensus import (
    ConsensusForces,
    ConsensusPlant,
)

STANDSTILL_MPS = 0.01         # every car slower than this is standing still (hil.runtime.plant_node)
DEFAULT_BITRATE = 500_000     # bit/s when neither the scenario nor the DBC gives one


def node_names(scenario: Scenario, names: list[str]) -> list[str]:
    return ["PLANT", "BCU"] + [f"BECU{i}" for i in range(1, scenario.train.cars + 1)]


class ConsensusTruth:
    """Ground truth of every plant step (1 ms), picklable: `columns()` -> t_s and `<quantity>_<k>`."""

    KEYS = ("x_m", "v_mps", "a_mps2", "force_N", "u_cmd", "phi_mps2", "skidding")

    def __init__(self, n: int) -> None:
        self.n = n
        self.t_us: list[int] = []
        self.rows: list[tuple] = []
        self.max_abs_dl_m: list[float] = [0.0] * max(n - 1, 0)   # over every step [m]

    def record(self, t_us: int, x: np.ndarray, v: np.ndarray, f: ConsensusForces, u: np.ndarray,
               gain: tuple[float, ...], masses: tuple[float, ...]) -> None:
        # φ_i/m_i as the observer's nominal model sees it: v̇ + K_b u/m (eq. (10) seed 003)
        phi = f.accel_mps2 + np.asarray(gain) * u / np.asarray(masses)
        self.t_us.append(t_us)
        self.rows.append((x.copy(), v.copy(), f.accel_mps2, f.fa_N, u.copy(), phi, f.skidding, f.dl_m))

    def columns(self) -> dict[str, np.ndarray]:
        cols: dict[str, np.ndarray] = {"t_s": np.asarray(self.t_us, dtype=np.int64) / 1e6}
        if not self.rows:
            return cols
        n = self.n
        stacked = [np.array([r[k] for r in self.rows]) for k in range(8)]
        for key, arr in zip(self.KEYS, stacked[:7], strict=True):
            for k in range(n):
                cols[f"{key}_{k + 1}"] = arr[:, k]
        zeros = np.zeros(len(self.t_us))
        for k in range(1, n + 1):         # quantities of the foundation's plant this model has not
            cols[f"slip_speed_mps_{k}"] = zeros
            cols[f"slip_ratio_{k}"] = zeros
            cols[f"wsp_valve_{k}"] = zeros
            cols[f"p_Pa_{k}"] = zeros
        for k in range(1, n):
            cols[f"coupler_dl_m_{k}"] = stacked[7][:, k - 1]
        return cols


class ConsensusPlantController:
    """The PLANT node of seed 003: force commands in (BECUn_CONS.ForceCmd), speed and displacement out
    (PLANT_CONS_CARn).  A car whose command has not arrived yet coasts (u = 0); afterwards it holds its
    last command (the paper's actuator has no fail-safe of its own)."""

    def __init__(self, plant: ConsensusPlant, sensor_period_us: int) -> None:
        self.plant = plant
        p = plant.p
        self.n = n = p.train.n_cars
        self.inputs = tuple(f"BECU{i}_CONS.ForceCmd" for i in range(1, n + 1))
        self.outputs = tuple(f"PLANT_CONS_CAR{i}.{s}" for i in range(1, n + 1)
                             for s in ("Speed", "Position", "Sample"))
        self.sensor_period_us = sensor_period_us
        self.u = np.zeros(n)
        self.truth = ConsensusTruth(n)
        self.standstill = False
        self._version = -1

    def glance(self) -> dict[str, np.ndarray]:
        s = self.plant.state
        return {"v_mps": s.v.copy(), "x_m": s.x.copy()}

    def step(self, now_us: int, rx) -> dict[str, float]:
        if rx.version != self._version:
            self._version = rx.version
            for k, key in enumerate(self.inputs):
                value = rx[key]
                if math.isfinite(value):
                    self.u[k] = value
        s = self.plant.state
        out = {}
        sample = (now_us // self.sensor_period_us) % SAMPLE_MODULO     # the cycle's sample counter
        for i in range(self.n):
            out[self.outputs[3 * i]] = max(0.0, float(s.v[i]))
            out[self.outputs[3 * i + 1]] = float(s.x[i]) % POSITION_WRAP_M    # the odometer wraps (DBC)
            out[self.outputs[3 * i + 2]] = sample
        x, v = s.x.copy(), s.v.copy()
        f = self.plant.step(self.u / 1.0)
        p = self.plant.p
        self.truth.record(now_us, x, v, f, self.u, p.brake_gain, p.train.masses_kg)
        self.truth.max_abs_dl_m = [float(d) for d in self.plant.max_abs_dl_m]
        self.standstill = bool(np.max(s.v) < STANDSTILL_MPS)
        return out


def _cycle_us(db: Database, name: str, dbc_name: str) -> int:
    try:
        msg = db.get_message_by_name(name)
    except KeyError:
        raise BindingError(f"consensus braking: {dbc_name} has no message {name!r}; it needs the seed-003 "
                           "frames "
                           "of dbc/train_brake.dbc (0x058-0x06F)") from None
    if not msg.cycle_time:
        raise BindingError(f"consensus braking: message {name} of {dbc_name} has no cycle time "
                           "(GenMsgCycleTime)")
    return int(msg.cycle_time) * 1000


def _frame_us(db: Database, name: str, rate: float) -> float:
    """Longest duration of frame `name` on the wire at `rate` bit/s (worst-case stuffing) [µs]."""
    msg = db.get_message_by_name(name)
    return frame_bits(msg.length, msg.is_extended_frame, True) * 1e6 / rate


def becu_offset_us(scenario: Scenario, db: Database, car: int) -> int:
    """When BECU `car` runs in its cycle [µs] (module doc): after its sensor frame has arrived.

    Bit-timed bus: sensor frames 1..car and BECU frames 1..car−1 at their worst-case stuffed length, so that
    the BECU always sees this cycle's sample (a BECU that runs before its sensor frame works on the sample
    of the cycle before: one more cycle of delay).  Ideal bus (the paper setting): the estimate the paper
    setting's results were produced with (5- and 8-byte frames, stuffing halfway)."""
    rate = scenario.bus.bitrate or declared_bitrate(db) or DEFAULT_BITRATE
    if scenario.bus.timing == "bit":
        t_s = _frame_us(db, f"PLANT_CONS_CAR{car}", rate)
        t_c = _frame_us(db, f"BECU{car}_CONS", rate)
        return round(car * t_s + (car - 1) * t_c) + 20
    t_s = (frame_bits(5, False, False) + frame_bits(5, False, True)) / 2 * 1e6 / rate
    t_c = (frame_bits(8, False, False) + frame_bits(8, False, True)) / 2 * 1e6 / rate
    return round(car * t_s + (car - 1) * t_c) + 20


def bcu_offset_us(scenario: Scenario, db: Database, dbc_name: str) -> int:
    """When the BCU sends CONS_REF [µs]: on the bit-timed bus after the consensus loop's frames of the cycle
    (CONS_REF has the highest priority: sent at the cycle's start it would delay every sensor frame and
    the BECUs would run on the previous sample); phase 0 when they leave no room or on the ideal bus."""
    if scenario.bus.timing != "bit":
        return 0
    n = scenario.train.cars
    rate = scenario.bus.bitrate or declared_bitrate(db) or DEFAULT_BITRATE
    end = becu_offset_us(scenario, db, n) + _frame_us(db, f"BECU{n}_CONS", rate)
    cycle = _cycle_us(db, f"BECU{n}_CONS", dbc_name)
    return round(end) if end + _frame_us(db, "CONS_REF", rate) < cycle else 0


def build_node(name: str, scenario: Scenario, db: Database, codec: Codec,
               dbc_name: str = "DBC") -> Node | None:
    n = scenario.train.cars
    c = scenario.consensus
    if name == "PLANT":
        plant = ConsensusPlant(consensus_plant_params(scenario))
        rx = [f"BECU{i}_CONS" for i in range(1, n + 1)]
        tx = [f"PLANT_CONS_CAR{i}" for i in range(1, n + 1)]
        periods = {_cycle_us(db, m, dbc_name) for m in tx}
        if len(periods) != 1:
            raise BindingError(f"consensus braking: the PLANT_CONS_CARn frames of {dbc_name} need one cycle "
                               "time, "
                               f"got {sorted(p // 1000 for p in periods)} ms")
        sensor_us = periods.pop()
        if sensor_us % plant.p.dt_us:
            raise BindingError(f"consensus braking: scenario key 'consensus.plant_step_us' = {plant.p.dt_us} "
                               f"does not divide the {sensor_us} us cycle of the PLANT_CONS_CARn frames "
                               f"of {dbc_name}")
        ctrl = ConsensusPlantController(plant, sensor_us)
        period, offset = plant.p.dt_us, 0
    elif name == "BCU":
        ctrl = VirtualLeader(VirtualLeaderParams(v0_mps=c.v_ref_kmh * KMH, decel_mps2=c.decel_kmh_s * KMH))
        rx, tx = [], ["CONS_REF"]
        period, offset = _cycle_us(db, "CONS_REF", dbc_name), bcu_offset_us(scenario, db, dbc_name)
    elif name.startswith("BECU") and name[4:].isdigit() and 1 <= int(name[4:]) <= n:
        i = int(name[4:])
        period = _cycle_us(db, f"BECU{i}_CONS", dbc_name)
        sample_us = _cycle_us(db, f"PLANT_CONS_CAR{i}", dbc_name)
        ctrl = ConsensusBecu(consensus_becu_params(scenario, i, sample_us, period))
        rx = [f"PLANT_CONS_CAR{i}", "CONS_REF"] + [f"BECU{j}_CONS" for j in range(1, n + 1) if j != i]
        tx = [f"BECU{i}_CONS", f"BECU{i}_CONS_DIAG"]
        offset = becu_offset_us(scenario, db, i) % period
    else:
        return None
    binding = Binding.build(db, name, ctrl.inputs, ctrl.outputs, rx, tx, dbc_name)
    node = Node(name, ctrl, binding, codec, db, period_us=period, offset_us=offset)
    if name.startswith("BECU") and scenario.bus.timing == "bit":    # frames take no time on the ideal bus
        stagger_diag(node, int(name[4:]), period)
    return node


def stagger_diag(node: Node, car: int, period_us: int) -> None:
    """Spread the BECUs' DIAG frames over the consensus cycles of their DBC cycle: BECU i sends its first in
    cycle (i − 1) mod k, k = DIAG cycle / consensus cycle.  Sent in the same cycle, six DIAG frames would
    overrun the cycle and delay the next cycle's sensor frames (a BECU would then run on the previous
    sample)."""
    for tx in node.tx:
        if tx.codec.name.endswith("_CONS_DIAG") and tx.cycle_us > period_us:
            tx.next_due_us += ((car - 1) % (tx.cycle_us // period_us)) * period_us

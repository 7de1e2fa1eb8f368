"""railhil's plant and BECU inside an FMU: the PythonFMU slaves that `railhil export-fmu` packs.

The FMU carries a small script (a subclass of `PlantSlave` or `NodeSlave`), the run's scenario as JSON and
its DBC in its resources; its binary is PythonFMU's, which runs the script in a Python that has railhil
installed.  Its variables carry the bench's port names (hil.fmi.ports), so the bench imports it back without
a map, and other tools see the units and descriptions of the DBC and of truth.csv.

The plant FMU steps railhil's plant (plant_sim.Plant) at the scenario's plant step and samples its sensors
at the sensor frames' cycle, as the plant node does: sensors are read at t = 0 and after every step that
ends on a multiple of that cycle, and held in between.  Truth outputs are computed when they are read.
The BECU FMU runs firmware_py's Becu: each doStep(t, h) steps the controller at t + h, the end of the step,
with the inputs set before it, and its outputs are those of that step (the bench steps it from one cycle's
release to the next, so the controller sees the times railhil's own node sees).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from pythonfmu import DefaultExperiment, Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer, Real

from firmware_py.rx import RxTable
from hil.can.codec import Codec
from hil.can.dbc import load_dbc
from hil.fmi.ports import (
    AGE_SUFFIX,
    COMMANDS,
    COUPLER_COLUMNS,
    SCENARIO_VALUES,
    SENSORS,
    TRUTH_COLUMNS,
    node_port,
    truth_name,
)
from hil.runtime.assembly import build_node, build_plant
from hil.scenario import params
from hil.scenario.load import parse_scenario

SCENARIO_FILE = "scenario.json"     # the resolved scenario, in the FMU's resources
DBC_FILE = "bench.dbc"              # its DBC

# PythonFMU 0.7's binary, loading the FMU's script (findClass in pythonfmu-export's PySlaveInstance.cpp), runs
# its code again in the module's namespace and then Py_DECREFs that namespace, which PyModule_GetDict only
# lent it: once per instance.  Unbalanced, the module's dict is freed under it, and the next garbage
# collection (or a second instance) crashes the process with SIGSEGV.  The script calls `hold_module_dict` at
# module level, so each run of it takes the reference its loader then gives back.
_HELD_MODULE_DICTS: list[dict] = []


def hold_module_dict(namespace: dict) -> None:
    """Keep one reference to an exported FMU script's module namespace (see above)."""
    _HELD_MODULE_DICTS.append(namespace)


def load_exported_scenario(resources: str | Path):
    """The scenario and DBC an exported FMU carries (its DBC is the copy in its resources)."""

    res = Path(resources)
    data = json.loads((res / SCENARIO_FILE).read_text(encoding="utf-8"))
    data["dbc"] = str(res / DBC_FILE)
    scenario = parse_scenario(data, str(res / SCENARIO_FILE))
    return scenario, load_dbc(res / DBC_FILE)


def _scenario_with(scenario, values: dict[str, float]):
    """The scenario with the FMU's parameters (hil.fmi.ports.SCENARIO_VALUES) as set."""
    train = scenario.train.model_copy(update={"initial_speed_kmh": float(values["train.initial_speed_kmh"]),
                                              "start_position_m": float(values["train.start_position_m"])})
    return scenario.model_copy(update={"train": train, "seed": int(values["seed"])})


class PlantSlave(Fmi2Slave):
    """railhil's plant of the packed scenario (module docstring)."""

    author = "railhil"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.scenario, self.db = load_exported_scenario(self.resources)
        s = self.scenario
        self.n = n = s.train.cars
        self.description = (f"railhil's plant of scenario {s.name!r}: {n} cars, couplers, wheel-rail "
                            "adhesion, pneumatic brakes and sensors (needs a Python with railhil installed)")
        self.default_experiment = DefaultExperiment(start_time=0.0, stop_time=s.max_duration_s,
                                                    step_size=self._dt_us() * 1e-6)
        self.values = {key: float(get(s)) for key, (_, _, get) in SCENARIO_VALUES.items()}
        for key, (_, description, _) in SCENARIO_VALUES.items():
            kind = Integer if key == "seed" else Real
            self.register_variable(kind(key, causality=Fmi2Causality.parameter,
                                        variability=Fmi2Variability.fixed, initial=Fmi2Initial.exact,
                                        description=description,
                                        getter=lambda key=key: self.values[key],
                                        setter=lambda v, key=key: self.values.__setitem__(key, v)))
        self.u, self.w, self.ps = np.zeros(n), np.zeros(n, dtype=np.int64), np.zeros(n)
        arrays = {"ValveCmd": self.u, "WspValve": self.w, "CylPressureSet": self.ps}
        for k in range(n):
            for sig in COMMANDS:
                arr = arrays[sig]
                kind, how = ((Integer, Fmi2Variability.discrete) if sig == "WspValve"
                             else (Real, Fmi2Variability.continuous))
                self.register_variable(kind(f"BECU{k + 1}_PRESS_CMD.{sig}", causality=Fmi2Causality.input,
                                            variability=how,
                                            getter=lambda arr=arr, k=k: arr[k],
                                            setter=lambda v, arr=arr, k=k: arr.__setitem__(k, v)))
        self.plant = None
        self.sensors = None
        self.readings = {sig: np.zeros(n) for sig in SENSORS}
        for k in range(n):
            for sig in SENSORS:
                self.register_variable(Real(f"PLANT_CAR{k + 1}_SENSORS.{sig}", causality=Fmi2Causality.output,
                                            initial=Fmi2Initial.exact,
                                            getter=lambda sig=sig, k=k: self.readings[sig][k]))
        self._truth = None
        for column in TRUTH_COLUMNS:
            for k in range(n - 1 if column in COUPLER_COLUMNS else n):
                self.register_variable(Real(truth_name(column, k + 1), causality=Fmi2Causality.output,
                                            initial=Fmi2Initial.exact,
                                            getter=lambda column=column, k=k: self._truth_value(column, k)))

    def _dt_us(self) -> int:
        return params.run_params(self.scenario).plant.dt_us

    def exit_initialization_mode(self) -> None:
        self.plant = build_plant(_scenario_with(self.scenario, self.values))
        self.dt_us = self.plant.params.dt_us
        self.sensor_period_us = int(self.db.get_message_by_name("PLANT_CAR1_SENSORS").cycle_time) * 1000
        self.t_us = 0
        self._sense()

    def _sense(self) -> None:
        s = self.plant.sense()
        for sig, arr in zip(SENSORS, (s.axle_speed_rad_s, s.cyl_pressure_Pa, s.accel_mps2), strict=True):
            self.readings[sig] = np.array(arr, dtype=float)

    def _truth_value(self, column: str, k: int) -> float:
        if self.plant is None:
            return 0.0
        if self._truth is None:
            self._truth = self.plant.truth_series([self.plant.truth_record()])
        return float(self._truth[column][0][k]) if column in self._truth else math.nan

    def do_step(self, current_time: float, step_size: float) -> bool:
        steps = round(step_size * 1e6 / self.dt_us)
        if steps < 1 or abs(steps * self.dt_us - step_size * 1e6) > 1e-3:
            self.log(f"step size {step_size} s is not a multiple of the plant's step {self.dt_us} us")
            return False
        for _ in range(steps):
            self.plant.step(self.u, self.w, self.ps)
            self.t_us += self.dt_us
            if self.t_us % self.sensor_period_us == 0:
                self._sense()
        self._truth = None
        return True


class NodeSlave(Fmi2Slave):
    """A node of the packed scenario — its controller, not its E2E or SecOC, which the bench adds — as an
    FMU (module docstring).  `NODE` names it (BECU3)."""

    author = "railhil"
    NODE = ""

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)

        self.scenario, db = load_exported_scenario(self.resources)
        node = build_node(self.NODE, self.scenario, db, Codec(db))
        self.controller = node.controller
        self.period_us = node.period_us
        self.description = (f"railhil's {self.NODE} of scenario {self.scenario.name!r}: its controller on a "
                            f"{node.period_us / 1000:g} ms cycle (needs a Python with railhil installed)")
        self.default_experiment = DefaultExperiment(start_time=0.0, stop_time=self.scenario.max_duration_s,
                                                    step_size=node.period_us * 1e-6)
        rx_msgs = [db.get_message_by_frame_id(fid).name for fid in node.binding.rx]
        tx_msgs = [msg for msg, _ in node.binding.tx]
        port = node_port(db, rx_msgs, tx_msgs)
        self.values: dict[str, float] = {}      # the controller's rx keys -> value
        self.keys_of: dict[str, list[str]] = {}   # message -> its rx keys
        self.ages: dict[str, float] = {m: -1.0 for m in rx_msgs}
        for fid, pairs in node.binding.rx.items():
            msg = db.get_message_by_frame_id(fid)
            for sig, key in pairs:
                q = port.inputs[f"{msg.name}.{sig}"]
                self.values[key] = 0.0      # until set (the bench sets NaN for "not received yet")
                self.keys_of.setdefault(msg.name, []).append(key)
                # a Real even for a whole-valued signal: NaN says "not received yet", as on the bench
                self.register_variable(Real(q.name, causality=Fmi2Causality.input, description=q.description,
                                            getter=lambda key=key: _finite(self.values[key]),
                                            setter=lambda v, key=key: self.values.__setitem__(key, v)))
        for msg in rx_msgs:
            self.register_variable(Real(f"{msg}.{AGE_SUFFIX}", causality=Fmi2Causality.input,
                                        getter=lambda msg=msg: self.ages[msg],
                                        setter=lambda v, msg=msg: self.ages.__setitem__(msg, v)))
        self.outputs: dict[str, float] = {}
        for msg, pairs in node.binding.tx:
            for sig, key in pairs:
                q = port.outputs.get(f"{msg}.{sig}")
                if q is None:
                    continue
                self.outputs.setdefault(key, 0.0)
                if q.integer:
                    self.register_variable(Integer(q.name, causality=Fmi2Causality.output,
                                                   variability=Fmi2Variability.discrete,
                                                   initial=Fmi2Initial.exact, description=q.description,
                                                   getter=lambda key=key: _whole(self.outputs[key])))
                else:
                    self.register_variable(Real(q.name, causality=Fmi2Causality.output,
                                                initial=Fmi2Initial.exact, description=q.description,
                                                getter=lambda key=key: _finite(self.outputs[key])))
        # what the controller reads (`rx["TargetDecel"]`, `rx.age_us(name, now)`): the inputs by the binding's
        # keys, each message received `MESSAGE.rx_age_s` before the step's end (negative: not received, NaN)
        self.rx = RxTable(self.values)
        self._pairs = {msg: [(key, key) for key in keys] for msg, keys in self.keys_of.items()}
        self._unreceived = {msg: dict.fromkeys(keys, math.nan) for msg, keys in self.keys_of.items()}

    def do_step(self, current_time: float, step_size: float) -> bool:
        now_us = round((current_time + step_size) * 1e6)
        rx = self.rx
        for msg, pairs in self._pairs.items():
            age_s = self.ages[msg]
            if math.isfinite(age_s) and age_s >= 0:
                rx.update(pairs, self.values, now_us - round(age_s * 1e6))
            else:
                rx.receive(self._unreceived[msg], now_us)
        out = self.controller.step(now_us, rx)
        for key, value in out.items():
            if key in self.outputs:
                self.outputs[key] = value
        return True


def _whole(value) -> int:
    """An integer output's value (a non-finite one as 0)."""
    v = _finite(value)
    return int(round(v)) if math.isfinite(v) else 0


def _finite(value) -> float:
    """A value as the FMU hands it out: a number (NaN, 'never received', stays NaN for a Real)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan

"""An FMU as the plant: the plant node (hil.runtime.plant_node.PlantController) steps it as it steps
railhil's own plant_sim.Plant.

`FmuPlant` has the plant's interface the node uses — `step(valve, wsp, pset)`, `sense()`, `truth_record()`,
`truth_series(snaps)`, `snapshot()` — so the node's sensor frames, fail-safe, sensor faults and truth log
are the same code with either plant, and a run with an FMU plant gets the same summary, report and
verdicts: the KPIs come from the truth the FMU gives (hil.fmi.ports.TRUTH_COLUMNS).

Its step is the plant's step (`[plant] dt`, 1 ms): each `step` sets the inputs that changed and calls doStep
once; the outputs are read once a sample, when the node asks for sensors or truth (every 10 ms).  The
truth columns the FMU does not give are derived where the bench can (acceleration from the speed samples,
slip ratio from slip speed and speed, the applied commands, coupler extension from positions) and are NaN
otherwise.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from hil.errors import FmuError
from hil.fmi.fmu import CoSimulation, FmuInfo, checking_only, open_fmu, refs
from hil.fmi.mapping import Wiring, read_map, wire
from hil.fmi.ports import (
    COMMANDS,
    COUPLER_COLUMNS,
    REQUIRED_TRUTH,
    SENSORS,
    TRUTH_COLUMNS,
    plant_port,
    truth_name,
)
from hil.runtime.plant_node import TRUTH_PERIOD_US
from plant_sim.adhesion import slip_ratio
from plant_sim.dynamics import car_constants, coupler_extension
from plant_sim.params import PlantParams
from plant_sim.sensors import Sensors


class FmuSnapshot(NamedTuple):
    """The plant's state now as the bench reads it (lists per car; NaN where the FMU gives nothing)."""

    x: list
    v: list
    s: list
    p: list
    tau: list


class FmuRecord(NamedTuple):
    """One truth sample: the connected outputs (bench units), the commands applied, and the cars' speeds."""

    outputs: np.ndarray
    u: np.ndarray
    w: np.ndarray
    ps: np.ndarray
    v: np.ndarray          # [m/s] per car (the plant node's standstill test reads it)


class FmuPlant:
    """The plant as an FMU, stepped at `params.dt_us` (see the module docstring)."""

    def __init__(self, info: FmuInfo, wiring: Wiring, params: PlantParams, n_cars: int,
                 map_name: str | None = None) -> None:
        self.info, self.wiring, self.params = info, wiring, params
        self.n = n = n_cars
        given = wiring.output_names()
        missing = [f"PLANT_CAR{k}_SENSORS.{s}" for k in range(1, n + 1) for s in SENSORS]
        missing += [truth_name(c, k) for c in REQUIRED_TRUTH for k in range(1, n + 1)]
        missing = [m for m in missing if m not in given]
        if missing:
            how = (f"map them under [outputs] of {map_name}" if map_name
                   else "give the FMU a map file ([plant] fmu_map)")
            more = f" (and {len(missing) - 4} more)" if len(missing) > 4 else ""
            raise FmuError(f"{info.path}: the plant FMU {info.model_name!r} gives no "
                           f"{', '.join(missing[:4])}{more}: the bench needs each car's sensors and truth "
                           f"{', '.join(REQUIRED_TRUTH)}; {how}")
        self._dt_us = params.dt_us
        self._dt_s = params.dt_us * 1e-6
        self._cc = car_constants(params.train)
        self._n_steps = 0
        self.bad_inputs = 0
        self.sim = None if checking_only() else CoSimulation(info, "PLANT", wiring.start)
        # inputs: the bench's commands, in the order of the wiring's connections
        self._in_refs = refs(info, [c.target for c in wiring.inputs])
        # each input's command, as (row of ValveCmd / WspValve / CylPressureSet, car): found once, not by
        # its name every step
        ports = {f"BECU{k + 1}_PRESS_CMD.{sig}": (row, k)
                 for k in range(n) for row, sig in enumerate(COMMANDS)}
        self._in_at = [ports[c.source] for c in wiring.inputs]
        self._in_ab = [(c.a, c.b) for c in wiring.inputs]
        self._last_in: list[float] | None = None
        # outputs: read all at once per sample
        self._out_names = [c.target for c in wiring.outputs]
        self._out_refs = refs(info, [c.source for c in wiring.outputs])
        self._out_a = np.array([c.a for c in wiring.outputs])
        self._out_b = np.array([c.b for c in wiring.outputs])
        index = {name: k for k, name in enumerate(self._out_names)}
        self._sensor_at = [[index[f"PLANT_CAR{k}_SENSORS.{s}"] for k in range(1, n + 1)] for s in SENSORS]
        self._truth_at = {column: [index.get(truth_name(column, k), -1)
                                   for k in range(1, (n - 1 if column in COUPLER_COLUMNS else n) + 1)]
                          for column in TRUTH_COLUMNS}
        self._read_at_step = -1
        self._out = np.full(len(self._out_names), math.nan)
        self._u = np.zeros(n)
        self._w = np.zeros(n, dtype=np.int64)
        self._ps = np.zeros(n)
        self._no_set = np.zeros(n)             # the set-points of a "valve" plant, which has none

    # the plant's interface (plant_sim.plant.Plant) as the plant node uses it
    @property
    def t_us(self) -> int:
        return self._n_steps * self._dt_us

    @property
    def n_cars(self) -> int:
        return self.n

    def _outputs(self) -> np.ndarray:
        """Every connected output now, in bench units (read from the FMU once a step at most)."""
        if self._read_at_step != self._n_steps:
            raw = np.asarray(self.sim.get(self._out_refs, len(self._out_names)), dtype=float)
            self._out = raw * self._out_a + self._out_b
            self._read_at_step = self._n_steps
        return self._out

    def _column(self, column: str) -> np.ndarray:
        out = self._outputs()
        return np.array([out[k] if k >= 0 else math.nan for k in self._truth_at[column]])

    @property
    def lead_position_m(self) -> float:
        return float(self._column("x_m")[0])

    @property
    def max_slip_mps(self) -> np.ndarray:
        return self._column("slip_speed_max_mps")

    def step(self, valve_cmd, wsp_valve, pressure_set=None) -> None:
        u = np.asarray(valve_cmd, dtype=float)
        w = np.asarray(wsp_valve)
        ps = self._no_set if pressure_set is None else np.asarray(pressure_set, dtype=float)
        if u.shape != (self.n,) or w.shape != (self.n,) or ps.shape != (self.n,):
            raise FmuError(f"FmuPlant.step: need {self.n} valve commands, WSP states and set-points, got "
                           f"shapes {u.shape}, {w.shape} and {ps.shape}")
        self._u[:], self._w[:], self._ps[:] = u, w, ps
        rows = (self._u, self._w, self._ps)
        values = [a * float(rows[row][k]) + b
                  for (row, k), (a, b) in zip(self._in_at, self._in_ab, strict=True)]
        if values != self._last_in:
            self.sim.set(self._in_refs, values)
            self._last_in = values
        self.sim.step(self._dt_s, self._n_steps * self._dt_us * 1e-6)
        self._n_steps += 1

    def sense(self) -> Sensors:
        out = self._outputs()
        speed, pressure, accel = (out[at] for at in self._sensor_at)
        return Sensors(axle_speed_rad_s=speed, cyl_pressure_Pa=pressure, accel_mps2=accel)

    def snapshot(self) -> FmuSnapshot:
        return FmuSnapshot(*(self._column(c).tolist() for c in ("x_m", "v_mps", "slip_speed_mps", "p_Pa",
                                                                "tau_Nm")))

    def truth_record(self) -> FmuRecord:
        """What the truth log keeps each sample."""
        return FmuRecord(self._outputs().copy(), self._u.copy(), self._w.copy(), self._ps.copy(),
                         self._column("v_mps"))

    def truth_series(self, snaps) -> dict[str, np.ndarray]:
        """The truth columns for the samples `snaps` (truth.csv's keys; see the module docstring)."""
        outs = np.array([s.outputs for s in snaps])
        cols: dict[str, np.ndarray] = {}
        for column, at in self._truth_at.items():
            cols[column] = np.column_stack([outs[:, k] if k >= 0 else np.full(len(outs), math.nan)
                                            for k in at]) if at else np.zeros((len(outs), 0))
        given = {column for column, at in self._truth_at.items() if any(k >= 0 for k in at)}
        v = cols["v_mps"]
        if "a_mps2" not in given:        # backward difference of the 10 ms samples
            a = np.zeros_like(v)
            if len(v) > 1:
                a[1:] = np.diff(v, axis=0) * (1e6 / TRUTH_PERIOD_US)
            cols["a_mps2"] = a
        if "slip_ratio" not in given:
            cols["slip_ratio"] = slip_ratio(cols["slip_speed_mps"], v)
        if "omega_rad_s" not in given:
            cols["omega_rad_s"] = (v - cols["slip_speed_mps"]) * (1.0 / self._cc.r_m)
        if "valve_cmd" not in given:
            cols["valve_cmd"] = np.array([s.u for s in snaps])
        if "wsp_valve" not in given:
            cols["wsp_valve"] = np.array([s.w for s in snaps], dtype=np.int64)
        else:
            cols["wsp_valve"] = np.nan_to_num(cols["wsp_valve"]).astype(np.int64)
        if "p_set_Pa" not in given:
            cols["p_set_Pa"] = np.array([s.ps for s in snaps])
        if "coupler_dl_m" not in given and self.n > 1:
            cols["coupler_dl_m"] = coupler_extension(cols["x_m"], self._cc)
        if "slip_speed_max_mps" not in given:
            cols["slip_speed_max_mps"] = np.maximum.accumulate(cols["slip_speed_mps"], axis=0)
        return cols

    def close(self) -> None:
        if self.sim is not None:
            self.sim.close()




def fmu_plant(scenario, db, params: PlantParams) -> FmuPlant:
    """The plant FMU of `scenario` ([plant] fmu, fmu_map), connected to the plant's port of its train."""

    spec = scenario.plant
    info = open_fmu(spec.fmu)
    fmu_map = read_map(spec.fmu_map) if spec.fmu_map else None
    wiring = wire(info, plant_port(db, scenario.train.cars), fmu_map, scenario, spec.fmu_map)
    return FmuPlant(info, wiring, params, scenario.train.cars, spec.fmu_map)

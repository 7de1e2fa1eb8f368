"""The bench's ports: the quantities the bench hands a plant or a node and takes back from it, by name.

An FMU connects to a port by its variables' names — a variable named as a port quantity is connected to it,
no map needed — or through a map file (hil.fmi.mapping).  The names are the bench's own:

- a node's port is its DBC signals, `MESSAGE.Signal`: what it receives (inputs), what it sends (outputs),
  and per received message `MESSAGE.rx_age_s`, the seconds since its last usable frame (negative: none yet);
- the plant's port is the plant node's: the pressure commands of each car's BECU in (`BECUk_PRESS_CMD.
  ValveCmd`, `.WspValve`, `.CylPressureSet`), the sensor frames out (`PLANT_CARk_SENSORS.AxleSpeed`,
  `.CylPressure`, `.AccelLong`), and the truth the KPIs come from, `truth.COLUMN_k` with the column names
  of truth.csv (`truth.v_mps_1`, `truth.x_m_1`, ...);
- the scenario's values an FMU may take as parameters or start values, by their scenario key
  (`train.initial_speed_kmh`, `train.start_position_m`, `seed`).

Units are the DBC's for signals and SI for truth (unit strings pint reads).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from cantools.database.can import Database, Message

from hil.can.attributes import bench_filled_signals

AGE_SUFFIX = "rx_age_s"          # MESSAGE.rx_age_s: seconds since that message's last usable frame
TRUTH_PREFIX = "truth."


@dataclass(frozen=True)
class Quantity:
    """One quantity of a port."""

    name: str
    unit: str | None            # pint's spelling; None: a pure number
    integer: bool               # takes whole values only (a state, a counter)
    lo: float
    hi: float
    description: str


#: truth.csv's per-car (and per-coupler) columns: name -> (unit, description).  Required of a plant FMU:
#: REQUIRED_TRUTH; the others the bench derives (DERIVED) or leaves NaN where the FMU does not give them
TRUTH_COLUMNS = {
    "x_m": ("m", "car centre position on the track"),
    "v_mps": ("m/s", "car speed"),
    "a_mps2": ("m/s^2", "car acceleration dv/dt"),
    "omega_rad_s": ("rad/s", "axle angular speed"),
    "slip_speed_mps": ("m/s", "wheel slip speed v - r*omega"),
    "slip_speed_max_mps": ("m/s", "largest slip speed since the start, over every plant step"),
    "slip_ratio": (None, "slip ratio (v - r*omega)/v"),
    "mu": (None, "adhesion coefficient in use"),
    "mu_opt": (None, "adhesion coefficient at the optimal slip"),
    "sigma_opt": (None, "optimal slip ratio"),
    "p_Pa": ("Pa", "brake cylinder pressure"),
    "tau_Nm": ("N*m", "brake torque on the wheel"),
    "p_set_Pa": ("Pa", "cylinder pressure set-point as applied"),
    "valve_cmd": (None, "EP valve command as applied (-1 vent .. +1 fill)"),
    "wsp_valve": (None, "WSP dump valve state as applied (0 FILL, 1 HOLD, 2 VENT)"),
    "brake_force_N": ("N", "adhesion force braking the car"),
    "coupler_dl_m": ("m", "coupler extension between car k and k+1"),
    "coupler_force_N": ("N", "coupler force between car k and k+1"),
}
COUPLER_COLUMNS = ("coupler_dl_m", "coupler_force_N")
REQUIRED_TRUTH = ("x_m", "v_mps", "slip_speed_mps")
#: what the bench computes itself when the FMU does not give it: from other truth or the applied inputs
DERIVED = ("a_mps2", "slip_ratio", "valve_cmd", "wsp_valve", "p_set_Pa", "coupler_dl_m")
SENSORS = ("AxleSpeed", "CylPressure", "AccelLong")         # PLANT_CARk_SENSORS, as plant_node sends them
COMMANDS = ("ValveCmd", "WspValve", "CylPressureSet")       # BECUk_PRESS_CMD, as plant_node reads them

#: scenario values an FMU may take: key -> (unit, description, getter)
SCENARIO_VALUES = {
    "train.initial_speed_kmh": ("km/h", "initial speed of the train", lambda s: s.train.initial_speed_kmh),
    "train.start_position_m": ("m", "track position of car 1's centre at the start",
                               lambda s: s.train.start_position_m),
    "seed": (None, "the run's seed (sensor noise)", lambda s: s.seed),
}


def signal_quantity(msg: Message, signal_name: str) -> Quantity:
    """A DBC signal as a port quantity: its unit, range and whether it takes whole values only."""
    sig = next(s for s in msg.signals if s.name == signal_name)
    scale, offset = float(sig.scale), float(sig.offset)
    integer = not sig.is_float and scale == 1.0 and float(offset).is_integer()   # states, counters, flags
    lo = -math.inf if sig.minimum is None else float(sig.minimum)
    hi = math.inf if sig.maximum is None else float(sig.maximum)
    return Quantity(f"{msg.name}.{sig.name}", sig.unit or None, integer, lo, hi, sig.comment or "")


def age_quantity(msg: Message) -> Quantity:
    return Quantity(f"{msg.name}.{AGE_SUFFIX}", "s", False, -1.0, math.inf,
                    f"seconds since the last usable {msg.name} frame (negative: none yet)")


@dataclass(frozen=True)
class Port:
    """The quantities of a plant or node port, by name."""

    inputs: dict[str, Quantity]       # what the bench gives
    outputs: dict[str, Quantity]      # what the bench takes


def _controller_signals(msg: Message) -> list[Quantity]:
    """The signals of a message that a node's controller fills or reads (not the bench's E2E, SecOC or alive
    counter)."""
    filled = bench_filled_signals(msg)
    return [signal_quantity(msg, sig.name) for sig in msg.signals if sig.name not in filled]


def node_port(db: Database, rx_messages: list[str], tx_messages: list[str]) -> Port:
    """A node's port: every signal of the messages it receives (and their ages), every signal of the messages
    it sends that the node's controller fills (not E2E, SecOC or alive counters: the bench fills those)."""
    inputs: dict[str, Quantity] = {}
    for name in rx_messages:
        msg = db.get_message_by_name(name)
        for q in (*_controller_signals(msg), age_quantity(msg)):
            inputs[q.name] = q
    outputs = {q.name: q for name in tx_messages for q in _controller_signals(db.get_message_by_name(name))}
    return Port(inputs, outputs)


def truth_name(column: str, k: int) -> str:
    """`truth.v_mps_1`: the truth column of car (or coupler) k, 1-based."""
    return f"{TRUTH_PREFIX}{column}_{k}"


def plant_port(db: Database, n_cars: int) -> Port:
    """The plant's port for an n-car train: the BECUs' pressure commands in, the sensor frames and truth
    out."""
    def of(message: str, signals: tuple[str, ...]) -> dict[str, Quantity]:
        quantities = [signal_quantity(db.get_message_by_name(message.format(k=k)), sig)
                      for k in range(1, n_cars + 1) for sig in signals]
        return {q.name: q for q in quantities}

    inputs = of("BECU{k}_PRESS_CMD", COMMANDS)
    outputs = of("PLANT_CAR{k}_SENSORS", SENSORS)
    for column, (unit, description) in TRUTH_COLUMNS.items():
        count = n_cars - 1 if column in COUPLER_COLUMNS else n_cars
        for k in range(1, count + 1):
            name = truth_name(column, k)
            where = "coupler" if column in COUPLER_COLUMNS else "car"
            outputs[name] = Quantity(name, unit, column == "wsp_valve", -math.inf, math.inf,
                                     f"{description} ({where} {k})")
    return Port(inputs, outputs)

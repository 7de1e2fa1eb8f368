"""The scenario model: every section of a scenario file, validated with pydantic.

The foundation's sections are here; each study's section is in its folder (hil/studies/<name>/
scenario.py) and joins the model through the registry.  Loading and --set are hil.scenario.load;
docs/scenarios.md documents the format, scenarios/default.toml is the reference example.
"""

from __future__ import annotations

import functools
from typing import Annotated, Literal

from pydantic import Field, create_model, field_validator, model_validator

from hil.scenario import registry
from hil.scenario.base import Strict
from hil.scenario.faults import FaultSpec

MAX_CARS = 8
RAIL_CONDITION_NAMES = ("extra_dry", "dry", "wet", "extra_wet")


_Strict = Strict


class TrainSpec(_Strict):
    cars: Annotated[int, Field(ge=1, le=MAX_CARS, description="number of cars, each with a BECU")] = 6
    mass_kg: Annotated[float, Field(gt=1000, le=200_000)] = 40_000.0
    masses_kg: list[Annotated[float, Field(gt=1000, le=200_000)]] | None = None
    initial_speed_kmh: Annotated[float, Field(ge=0, le=400)] = 90.0
    start_position_m: float = 0.0
    # one lumped wheelset per car: J [kg m²]; None = plant_sim's TrainParams default
    wheel_inertia_kgm2: Annotated[float, Field(gt=0, le=100_000)] | None = None
    running_resistance: bool = True   # false: no Davis resistance (seed 001's model has none)

    @model_validator(mode="after")
    def _masses_match_cars(self) -> TrainSpec:
        if self.masses_kg is not None and len(self.masses_kg) != self.cars:
            raise ValueError(f"masses_kg has {len(self.masses_kg)} entries for {self.cars} cars")
        return self

    def masses(self) -> tuple[float, ...]:
        return tuple(self.masses_kg) if self.masses_kg is not None else (self.mass_kg,) * self.cars


class RailSegment(_Strict):
    from_m: float
    condition: Literal["extra_dry", "dry", "wet", "extra_wet"] | None = None
    theta: tuple[float, float, float] | None = None
    transition_m: Annotated[float, Field(ge=0)] = 0.0   # blend from the previous segment over this length

    @model_validator(mode="after")
    def _one_of(self) -> RailSegment:
        if (self.condition is None) == (self.theta is None):
            raise ValueError("give exactly one of 'condition' (a name) or 'theta' ([θ1, θ2, θ3])")
        return self


class GradientPoint(_Strict):
    from_m: float
    permille: Annotated[float, Field(ge=-60, le=60)]


class CurvePoint(_Strict):
    from_m: float
    radius_m: Annotated[float, Field(ge=0)]   # 0 = straight


class RailRow(_Strict):
    x_m: float
    theta: tuple[Annotated[float, Field(gt=0)], Annotated[float, Field(ge=0)], Annotated[float, Field(gt=0)]]


class TrackSpec(_Strict):
    rail: list[RailSegment] = Field(default_factory=lambda: [RailSegment(from_m=0.0, condition="dry")])
    # θ(x) as a table instead of segments: linear between rows, constant beyond the ends
    rail_table: list[RailRow] | None = None
    gradient: list[GradientPoint] = Field(default_factory=list)
    curves: list[CurvePoint] = Field(default_factory=list)
    # fixed balises (track positions [m], increasing): the train's BTM reports each passage of car 1's front
    # (PLANT_BTM); a BCU doing precise stopping re-anchors its odometer on them
    balises: list[float] = Field(default_factory=list)

    @field_validator("balises")
    @classmethod
    def _balises_increasing(cls, v):
        if any(b <= a for a, b in zip(v, v[1:], strict=False)):
            raise ValueError(f"balise positions must increase strictly, got {v}")
        return v

    @field_validator("rail", "gradient", "curves")
    @classmethod
    def _increasing(cls, v):
        xs = [p.from_m for p in v]
        if any(b <= a for a, b in zip(xs, xs[1:], strict=False)):
            raise ValueError(f"from_m must increase strictly, got {xs}")
        return v

    @field_validator("rail")
    @classmethod
    def _nonempty(cls, v):
        if not v:
            raise ValueError("needs at least one segment")
        return v

    @field_validator("rail_table")
    @classmethod
    def _table_increasing(cls, v):
        if v is not None:
            xs = [r.x_m for r in v]
            if not xs or any(b <= a for a, b in zip(xs, xs[1:], strict=False)):
                raise ValueError(f"needs rows with strictly increasing x_m, got {xs}")
        return v


class DeskEvent(_Strict):
    at_s: Annotated[float, Field(ge=0)]
    brake_step: Annotated[int, Field(ge=0, le=7)] | None = None
    emergency: bool | None = None
    target_stop_m: float | None = None


class DeadlineSpec(_Strict):
    """When a real-time cycle is a deadline miss and when a run still holds real time (hil.runtime.probe,
    hil.runtime.outcome.realtime_verdict).  A cycle released more than max(miss_min_us, miss_period_pct %
    of its period) after its deadline is a miss; a miss at an instant the machine probe was late too is the
    machine's, any other the bench's.  The run holds real time when, for every simulated node (the plant
    in its steps), the bench's misses are at most budget_pct % of its cycles and none is later than
    max_late_periods of its period."""

    miss_min_us: Annotated[int, Field(ge=0, le=1_000_000)] = 500
    miss_period_pct: Annotated[float, Field(ge=0, le=100)] = 5.0
    budget_pct: Annotated[float, Field(ge=0, le=100)] = 0.1
    max_late_periods: Annotated[float, Field(gt=0, le=1000)] = 1.0


class RealtimeSpec(_Strict):
    interface: str = "udp_multicast"
    channel: str | None = None        # None: a channel of this run's own (udp_multicast group/port)
    # simulated seconds per wall second: 1.0 = real time, 0.5 = half speed (for slow or loaded hosts)
    speed: Annotated[float, Field(gt=0, le=1)] = 1.0
    # "grouped": every simulated ECU in one process with one bus connection, each frame received once, the
    # plant in its own (plant_process = "shared": in the ECUs' process too); "per-node": one OS process per
    # node (isolation: kill -9 of one ECU; nodes spread over hosts)
    hosting: Literal["grouped", "per-node"] = "grouped"
    plant_process: Literal["own", "shared"] = "own"
    # "frames": the plant is woken when a frame of it is due and computes its 1 ms steps since (commands
    # applied at the step their reception time falls in); "steps": woken every 1 ms (hil.runtime.host)
    plant_wake: Literal["frames", "steps"] = "frames"
    # "auto": SCHED_FIFO, locked memory and CPU affinity where the OS permits (else nice, else as is);
    # "normal": ask for nothing (hil.runtime.rtos)
    scheduling: Literal["auto", "normal"] = "auto"
    # with scheduling "auto" and grouped hosting: the plant and the ECUs' process each on a CPU of its own.
    # Off by default: on the 2-core development VM it made the 10 ms nodes' p99 lateness worse, not better
    # (docs/lockstep-and-realtime.md)
    pin_cpus: bool = False
    # with scheduling "auto": the idle-state exit latency every CPU is held within during the run [µs]
    # (Linux PM QoS, /dev/cpu_dma_latency, root only; cyclictest asks for 0): 0 = an idle CPU polls
    # instead of halting, so a wake-up at a deadline does not first bring a halted CPU back
    # (hil.runtime.rtos.hold_cpu_latency); "off": ask nothing.  Off by default: on the 2-core development
    # VM it cut the 10 ms nodes' p99 lateness to 0 but doubled the machine's stalls and left the bench's
    # misses as they were (docs/lockstep-and-realtime.md)
    cpu_latency_us: int | Literal["off"] = "off"
    # sleep until a margin before each deadline, then poll out the rest; the margin is measured on this
    # machine for calibration_s before the run (its sleep lateness, hil.runtime.rtos.sleep_lateness)
    precise_wait: bool = True
    calibration_s: Annotated[float, Field(ge=0.1, le=10)] = 1.0
    # external nodes ([nodes.NAME] external, --external): the run waits this long for the first frame of
    # each before it starts [s]
    external_wait_s: Annotated[float, Field(gt=0, le=600)] = 30.0
    deadline: DeadlineSpec = Field(default_factory=DeadlineSpec)

    @field_validator("cpu_latency_us", mode="before")
    @classmethod
    def _latency_or_off(cls, v):
        if v == "off" or (isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= 2**31 - 1):
            return v
        raise ValueError(f'{v!r} is not a latency: expected an integer number of µs ≥ 0, or "off"')


class TraceSpec(_Strict):
    """The run's trace: every frame of the bus, written by python-can's writer for the format, as
    trace.<format> in the run folder.  BLF opens in Vector tools and SavvyCAN; MF4 (ASAM MDF 4 bus
    logging, through asammdf) in CANape, asammdf and most automotive measurement tools; ASC is Vector's
    text; log is candump -L text."""

    format: Literal["blf", "mf4", "asc", "log"] = "blf"


class BusSpec(_Strict):
    """The lockstep bus.  Real-time runs get their timing from the real bus instead."""

    # "bit": frame durations, arbitration, transmit queues, delivery at end of frame (hil.can.bustiming);
    # "ideal": every frame delivered the instant it is sent (no bus timing at all)
    timing: Literal["bit", "ideal"] = "bit"
    bitrate: Annotated[int, Field(ge=10_000, le=1_000_000)] | None = None   # bit/s; default: DBC Baudrate
    stuffing: Literal["exact", "worst", "none"] = "exact"


class NodeTiming(_Strict):
    """Release jitter, clock drift and start delay of one node's cycle (lockstep).

    Cycle k of a node with period T and phase offset o is released at
    start_delay + o + k·T·(1 + drift_ppm·1e-6) + U(jitter_min_us, jitter_max_us), seeded; the jitter
    does not accumulate.  Without a value here, the sender node's CANdb++ attributes CANoeStartDelay
    [ms], CANoeDrift [%] and CANoeJitterMin/Max [% of the period] are used when the DBC has them.
    `external` (real time) takes the node out of the simulation: a device under test sends its frames."""

    jitter_min_us: Annotated[int, Field(ge=-1_000_000, le=1_000_000)] | None = None
    jitter_max_us: Annotated[int, Field(ge=-1_000_000, le=1_000_000)] | None = None
    drift_ppm: Annotated[float, Field(ge=-100_000, le=100_000)] | None = None
    start_delay_us: Annotated[int, Field(ge=0, le=60_000_000)] | None = None
    # real time: the node is not simulated; its frames come from the bus (a device under test, another
    # process or host: `railhil node`); the run judges them like any node's
    external: bool = False
    # an FMU as the node's controller (hil.fmi, docs/fmu.md), and the map of its variables where they are
    # not named as the node's signals; the bench adds E2E and SecOC as for any node
    fmu: str | None = None
    fmu_map: str | None = None

    @model_validator(mode="after")
    def _ordered(self) -> NodeTiming:
        lo, hi = self.jitter_min_us, self.jitter_max_us
        if lo is not None and hi is not None and hi < lo:
            raise ValueError(f"jitter_max_us {hi} is below jitter_min_us {lo}")
        return self


class MessageTiming(_Strict):
    """Extra delay between a node producing a frame and the frame entering its transmit queue:
    uniform in [delay_min_us, delay_max_us], seeded (equal bounds: a fixed delay)."""

    delay_min_us: Annotated[int, Field(ge=0, le=1_000_000)] = 0
    delay_max_us: Annotated[int, Field(ge=0, le=1_000_000)] = 0

    @model_validator(mode="after")
    def _ordered(self) -> MessageTiming:
        if self.delay_max_us < self.delay_min_us:
            raise ValueError(f"delay_max_us {self.delay_max_us} is below delay_min_us {self.delay_min_us}")
        return self


class PlantSpec(_Strict):
    """Plant options (seed 001): adhesion curve family, cylinder model, brake hysteresis."""

    # "track": seed 000's curve from [track] rail (the default); "slip_speed": seed 001's μ(s) with the
    # peak below, the same on the whole track ([track] rail is then not used for adhesion)
    adhesion: Literal["track", "slip_speed"] = "track"
    mu_peak: Annotated[float, Field(gt=0, lt=2)] = 0.2              # μ̂: f_max = μ̂ M g (seed 001 §IV-A)
    slip_peak_mps: Annotated[float, Field(gt=0, lt=10)] = 0.155     # ŝ: slip speed of the peak [m/s]
    # beyond the peak μ(s) never below slide_ratio × μ̂: a sliding wheel's friction (0 = seed 001's curve)
    slide_ratio: Annotated[float, Field(ge=0, lt=1)] = 0.0
    # a car's actuators without a usable pressure command hold its cylinder this long, then fill it [s]
    # (hil.runtime.plant_node.FAILSAFE_HOLD_S: the WSP safety timer's 5 s); 0 fills at once
    failsafe_hold_s: Annotated[float, Field(ge=0, le=60)] = 5.0
    # "valve": EP valve driven by ValveCmd; "lag": cylinder follows CylPressureSet with Tp (eq. 4)
    pressure_model: Literal["valve", "lag"] = "valve"
    tp_s: Annotated[float, Field(gt=0, le=5)] = 0.05                # Tp [s], seed 001 §IV
    # brake hysteresis (eq. 6): squeeze gain ᾱ = α̲ [N m/Pa], squeeze line's zero [Pa], release line
    # this far above it [Pa]; None = plant_sim's BrakeParams defaults
    brake_gain_Nm_per_Pa: Annotated[float, Field(gt=0, le=10)] | None = None
    brake_preload_Pa: Annotated[float, Field(ge=0, le=400e3)] | None = None
    hysteresis_Pa: Annotated[float, Field(ge=0, le=400e3)] | None = None
    # seed 004 eqs. (24)-(25): pad friction that varies with sliding speed and disc temperature (plant_sim
    # PadParams); the amplitudes and the disc's initial temperature rise may be changed
    pad_friction: bool = False
    pad_speed_amplitude: Annotated[float, Field(gt=-1, le=2)] | None = None     # n_v of eq. (25)
    pad_cold_amplitude: Annotated[float, Field(gt=-1, le=2)] | None = None      # n_T of eq. (25)
    disc_temp_rise_K: Annotated[float, Field(ge=0, le=600)] = 0.0              # T_d at the start [K]
    # an FMU as the plant (hil.fmi, docs/fmu.md): its file, and the map of its variables where they are not
    # named as the bench's port (paths beside the scenario; given by --set, beside the working directory)
    fmu: str | None = None
    fmu_map: str | None = None


class SensorSpec(_Strict):
    """Sensor noise (std); None = plant_sim's SensorParams defaults."""

    accel_noise_std_mps2: Annotated[float, Field(ge=0, le=10)] | None = None
    axle_speed_noise_std_rad_s: Annotated[float, Field(ge=0, le=10)] | None = None
    pressure_noise_std_Pa: Annotated[float, Field(ge=0, le=1e5)] | None = None


class BcuSpec(_Strict):
    """BCU options: target deceleration of brake steps 0..7 [m/s²] and the jerk limit [m/s³].  The
    BCU's optional functions have sections of their own ([decel_feedback], [precise_stop])."""

    step_decel_mps2: list[Annotated[float, Field(ge=0, le=20)]] | None = None
    jerk_limit_mps3: Annotated[float, Field(gt=0, le=1000)] | None = None

    @field_validator("step_decel_mps2")
    @classmethod
    def _eight(cls, v):
        if v is not None and (len(v) != 8 or v[0] != 0.0):
            raise ValueError(f"needs 8 values (steps 0..7) starting with 0.0, got {v}")
        return v

    def full_service_mps2(self) -> float | None:
        """Step 7's deceleration when the scenario gives the table (None: the BCU's default table)."""
        return None if self.step_decel_mps2 is None else self.step_decel_mps2[7]


class BecuSpec(_Strict):
    """BECU options: control law (seed 001 eq. 16) and WSP thresholds.  The reference governor has a
    section of its own ([wheel_slip])."""

    control: Literal["pressure", "decel"] = "pressure"
    kp_bar_per_g: Annotated[float, Field(ge=0, le=1000)] = 5.0          # K_P of eq. (16)
    ki_bar_per_g_s: Annotated[float, Field(ge=0, le=10_000)] = 40.0     # K_I of eq. (16)
    # WSP (seed 001 §II-C): vent above this estimated slip [m/s], refill below wsp_refill_slip_mps;
    # None = the BECU's speed-dependent default thresholds
    wsp_vent_slip_mps: Annotated[float, Field(gt=0, le=10)] | None = None
    wsp_refill_slip_mps: Annotated[float, Field(gt=0, le=10)] | None = None
    wheel_trust_slip_mps: Annotated[float, Field(ge=0, le=10)] | None = None   # speed estimator
    # leaving WSP, the decel PI resumes where it was frozen ("freeze") or from u = 0 ("handover")
    wsp_resume: Literal["freeze", "handover"] = "freeze"
    # "dump": WSP vents to zero and refills to the demand; "slip": it vents at a slide's onset and only until
    # the wheel turns back, holds, and refills no higher than a ceiling learnt from the pressure at the
    # slide's onset (firmware_py.wsp.slip_ceiling, early_vent)
    wsp_mode: Literal["dump", "slip"] = "dump"
    # the slip mode's pressure ceiling (firmware_py.wsp.WspParams; None: its defaults): the fraction of the
    # pressure at the slide's onset it starts at, its rise in FILL [bar/s], and the time in FILL without a
    # new slide after which it is dropped [s]
    wsp_ceiling_fraction: Annotated[float, Field(gt=0, le=1)] | None = None
    wsp_ceiling_rise_bar_per_s: Annotated[float, Field(ge=0, le=100)] | None = None
    wsp_ceiling_release_s: Annotated[float, Field(gt=0, le=60)] | None = None

    @model_validator(mode="after")
    def _consistent(self) -> BecuSpec:
        ceiling = [k for k in ("wsp_ceiling_fraction", "wsp_ceiling_rise_bar_per_s", "wsp_ceiling_release_s")
                   if getattr(self, k) is not None]
        if ceiling and self.wsp_mode != "slip":
            raise ValueError(f"{ceiling[0]} sets the slip-controlling WSP's ceiling: it needs "
                             f"wsp_mode = 'slip' (got {self.wsp_mode!r})")
        if (self.wsp_vent_slip_mps is None) != (self.wsp_refill_slip_mps is None):
            raise ValueError("give both wsp_vent_slip_mps and wsp_refill_slip_mps, or neither")
        if self.wsp_vent_slip_mps is not None and self.wsp_refill_slip_mps > self.wsp_vent_slip_mps:
            raise ValueError(f"wsp_refill_slip_mps {self.wsp_refill_slip_mps} is above wsp_vent_slip_mps "
                             f"{self.wsp_vent_slip_mps}")
        return self


class SecOcSpec(_Strict):
    """Keys of the authenticated messages (DBC attribute SecOCDataID): AES-128, 32 hex digits."""

    key: str | None = None       # every authenticated message; default: hil.runtime.node.DEV_SECOC_KEY
    keys: dict[str, str] = Field(default_factory=dict)   # by message name, over `key`
    # a TOML file with `key` and/or `[keys]` as above (path beside the scenario; else
    # $RAILHIL_SECOC_KEY_FILE), so that keys need not live in the scenario; its keys come under the scenario's
    key_file: str | None = None
    # true: a run never falls back to the development key (a bench with a real device on the bus)
    require_key: bool = False
    # freshness acceptance window [frames]: the longest outage a receiver survives (255 frames = 2.55 s
    # at 10 ms); beyond it the 8 transmitted bits cannot tell how many frames were lost
    window: Annotated[int, Field(ge=1, le=255)] = 255

    @field_validator("key")
    @classmethod
    def _hex_key(cls, v):
        if v is not None:
            _check_key(v)
        return v

    @field_validator("keys")
    @classmethod
    def _hex_keys(cls, v):
        for name, text in v.items():
            _check_key(text, name)
        return v


def _check_key(text: str, name: str | None = None) -> None:
    try:
        ok = len(bytes.fromhex(text)) == 16
    except ValueError:
        ok = False
    if not ok:
        what = f"key of {name}" if name else "key"
        raise ValueError(f"{what} must be 16 bytes as 32 hex digits (AES-128)")


class DeviceRef(_Strict):
    """A device that takes a node's place (hil.devices, docs/devices.md): its device file (a path beside the
    scenario), and for real-time runs the python-can bus it sits on where that is not the file's [bus]."""

    file: str
    bus: dict[str, str | int | float | bool] | None = None


class ScenarioBase(_Strict):
    """The foundation's part of a scenario.  `Scenario` (below) is this plus one optional section per
    study, from the registry (hil.scenario.registry): a study is part of a run when its section is
    present."""

    name: str = "unnamed"
    description: str = ""
    seed: int = 0
    max_duration_s: Annotated[float, Field(gt=0, le=3600)] = 120.0
    end_after_standstill_s: Annotated[float, Field(ge=0, le=60)] = 1.0
    dbc: str | None = None            # path relative to the scenario file; default dbc/train_brake.dbc
    train: TrainSpec = Field(default_factory=TrainSpec)
    track: TrackSpec = Field(default_factory=TrackSpec)
    desk: list[DeskEvent] = Field(default_factory=list)
    realtime: RealtimeSpec = Field(default_factory=RealtimeSpec)
    bus: BusSpec = Field(default_factory=BusSpec)
    trace: TraceSpec = Field(default_factory=TraceSpec)
    nodes: dict[str, NodeTiming] = Field(default_factory=dict)        # by node name, e.g. BECU3
    messages: dict[str, MessageTiming] = Field(default_factory=dict)  # by DBC message name
    plant: PlantSpec = Field(default_factory=PlantSpec)
    sensors: SensorSpec = Field(default_factory=SensorSpec)
    bcu: BcuSpec = Field(default_factory=BcuSpec)
    becu: BecuSpec = Field(default_factory=BecuSpec)
    faults: list[FaultSpec] = Field(default_factory=list)    # hil.scenario.faults; injected by hil.safety
    secoc: SecOcSpec = Field(default_factory=SecOcSpec)      # authentication keys
    devices: dict[str, DeviceRef] = Field(default_factory=dict)   # by the node each replaces, e.g. BECU3

    @field_validator("desk")
    @classmethod
    def _sorted(cls, v):
        ts = [e.at_s for e in v]
        if ts != sorted(ts):
            raise ValueError(f"desk events must be in time order, got at_s {ts}")
        return v

    @model_validator(mode="after")
    def _consistent(self) -> ScenarioBase:
        behind = [e.target_stop_m for e in self.desk
                  if e.target_stop_m is not None and e.target_stop_m <= self.train.start_position_m]
        if behind:
            raise ValueError(f"desk target_stop_m {behind[0]} m is not ahead of train.start_position_m "
                             f"{self.train.start_position_m} m")
        for study in registry.active(self):             # each study checks its section against the rest
            if study.check is not None:
                study.check(self)
        return self


@functools.cache
def scenario_model() -> type[ScenarioBase]:
    """The scenario model: ScenarioBase and one optional section per registered study."""
    sections = {s.section: (s.spec | None, Field(default=None, description=f"{s.title} ({s.paper})"))
                for s in registry.studies()}
    model = create_model("Scenario", __base__=ScenarioBase, __module__="hil.scenario", **sections)
    model.__doc__ = ("A scenario: the foundation's sections (ScenarioBase) and the studies' "
                     f"({', '.join(sections)}).")
    return model


def __getattr__(name: str):
    # `Scenario` is built on first use: its sections come from the study registry, whose packages import
    # this module's sections (hil.scenario.base) while they load
    if name == "Scenario":
        return scenario_model()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

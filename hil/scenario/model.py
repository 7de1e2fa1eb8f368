"""Scenario files: TOML, validated at load with pydantic.

A bad key or value gives one ScenarioError line naming the file, the key, the value and what is
allowed (exit code 2 at the CLI).  The README documents the format; scenarios/default.toml is the
reference example.
"""

from __future__ import annotations

import difflib
import tomllib
import types
import typing
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, Field, ValidationError, field_validator, model_validator

from hil.errors import ScenarioError
from hil.scenario.base import Strict
from hil.scenario.faults import FaultSpec
from hil.spec_acd import AcdSpec
from hil.spec_consensus import ConsensusSpec
from hil.spec_preview import PreviewSpec

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


class RealtimeSpec(_Strict):
    interface: str = "udp_multicast"
    channel: str | None = None        # None: a channel of this run's own (udp_multicast group/port)
    # simulated seconds per wall second: 1.0 = real time, 0.5 = half speed (for slow or loaded hosts)
    speed: Annotated[float, Field(gt=0, le=1)] = 1.0


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
    [ms], CANoeDrift [%] and CANoeJitterMin/Max [% of the period] are used when the DBC has them."""

    jitter_min_us: Annotated[int, Field(ge=-1_000_000, le=1_000_000)] | None = None
    jitter_max_us: Annotated[int, Field(ge=-1_000_000, le=1_000_000)] | None = None
    drift_ppm: Annotated[float, Field(ge=-100_000, le=100_000)] | None = None
    start_delay_us: Annotated[int, Field(ge=0, le=60_000_000)] | None = None

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


class SensorSpec(_Strict):
    """Sensor noise (std); None = plant_sim's SensorParams defaults."""

    accel_noise_std_mps2: Annotated[float, Field(ge=0, le=10)] | None = None
    axle_speed_noise_std_rad_s: Annotated[float, Field(ge=0, le=10)] | None = None
    pressure_noise_std_Pa: Annotated[float, Field(ge=0, le=1e5)] | None = None


class BcuSpec(_Strict):
    """BCU options: target deceleration of brake steps 0..7 [m/s²], the jerk limit [m/s³], and the
    deceleration feedback of seed 004 §5."""

    step_decel_mps2: list[Annotated[float, Field(ge=0, le=20)]] | None = None
    jerk_limit_mps3: Annotated[float, Field(gt=0, le=1000)] | None = None
    # seed 004 §5: true = closed loop, false = the function monitors only (the open-loop BCU, for
    # comparison; KPIs and plot as for true), absent = not fitted
    decel_feedback: bool | None = None
    # the friction-coefficient set μ(v, t): built from the plant's pad model on the brake-disc bench
    # ("bench", needs plant.pad_friction) or none (the loop's trim alone)
    friction_set: Literal["bench", "none"] = "bench"
    friction_set_fill: Literal["fraction", "time"] = "fraction"   # how untested speed classes are filled
    feedback_tq_s: Annotated[float, Field(gt=0, le=5)] = 0.1     # T_q of eq. (33) [s]
    # seed 002: precise stopping at the [[desk]] target_stop_m: "none" (not fitted), the paper's adaptive
    # search with united attempt and work steps without ("adaptive", Fig. 2) or with the differentiation
    # unit ("adaptive_diff", Fig. 3), or the modern baseline "pi" (curve tracking, PI + feed-forward)
    stopping: Literal["none", "adaptive", "adaptive_diff", "pi"] = "none"
    # the braking curve's planned deceleration a_p [m/s²]: braking starts where a stop at a_p ends at the
    # target (at once, and harder, when the target is nearer)
    stop_decel_mps2: Annotated[float, Field(gt=0, le=5)] = 0.6

    @field_validator("step_decel_mps2")
    @classmethod
    def _eight(cls, v):
        if v is not None and (len(v) != 8 or v[0] != 0.0):
            raise ValueError(f"needs 8 values (steps 0..7) starting with 0.0, got {v}")
        return v


class BecuSpec(_Strict):
    """BECU options: control law (seed 001 eq. 16), WSP thresholds, reference governor (eq. 9)."""

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
    governor: bool = False
    slip_max_mps: Annotated[float, Field(gt=0, le=1)] = 0.1              # s̄ of eq. (8)
    governor_margin: Annotated[float, Field(ge=0, lt=0.5)] = 0.005       # torque margin, fraction of τ̄

    @model_validator(mode="after")
    def _consistent(self) -> BecuSpec:
        if self.governor and self.control != "decel":
            raise ValueError("governor = true needs control = 'decel'")
        if (self.wsp_vent_slip_mps is None) != (self.wsp_refill_slip_mps is None):
            raise ValueError("give both wsp_vent_slip_mps and wsp_refill_slip_mps, or neither")
        if self.wsp_vent_slip_mps is not None and self.wsp_refill_slip_mps > self.wsp_vent_slip_mps:
            raise ValueError(f"wsp_refill_slip_mps {self.wsp_refill_slip_mps} is above wsp_vent_slip_mps "
                             f"{self.wsp_vent_slip_mps}")
        return self


class ReportSpec(_Strict):
    """What the run reports beyond the standard KPIs."""

    # the paper figure this scenario redoes: its published numbers are printed next to ours in the run
    # summary (hil.report.kpis); the seed-001 KPIs themselves are computed for every control = "decel" run
    paper_figure: Literal["seed001_fig8", "seed001_fig9"] | None = None
    # steady state = the last this many seconds of the braking window (at most its second half) [s]
    steady_state_window_s: Annotated[float, Field(gt=0, le=600)] = 10.0


class SecOcSpec(_Strict):
    """Keys of the authenticated messages (DBC attribute SecOCDataID): AES-128, 32 hex digits."""

    key: str | None = None       # every authenticated message; default: hil.runtime.node.DEV_SECOC_KEY
    keys: dict[str, str] = Field(default_factory=dict)   # by message name, over `key`
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


class Scenario(_Strict):
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
    nodes: dict[str, NodeTiming] = Field(default_factory=dict)        # by node name, e.g. BECU3
    messages: dict[str, MessageTiming] = Field(default_factory=dict)  # by DBC message name
    plant: PlantSpec = Field(default_factory=PlantSpec)
    sensors: SensorSpec = Field(default_factory=SensorSpec)
    bcu: BcuSpec = Field(default_factory=BcuSpec)
    becu: BecuSpec = Field(default_factory=BecuSpec)
    report: ReportSpec = Field(default_factory=ReportSpec)

    @model_validator(mode="after")
    def _governor_needs_curve(self) -> Scenario:
        if (self.bcu.decel_feedback is not None and self.bcu.friction_set == "bench"
                and not self.plant.pad_friction):
            raise ValueError("bcu.friction_set = 'bench' builds the set from the plant's pad model: it needs "
                             "plant.pad_friction = true (or bcu.friction_set = 'none')")
        if self.bcu.stopping != "none" and not any(e.target_stop_m is not None for e in self.desk):
            raise ValueError(f"bcu.stopping = '{self.bcu.stopping}' needs a [[desk]] event with "
                             f"target_stop_m (the target stop point, track position [m])")
        behind = [e.target_stop_m for e in self.desk
                  if e.target_stop_m is not None and e.target_stop_m <= self.train.start_position_m]
        if behind:
            raise ValueError(f"desk target_stop_m {behind[0]} m is not ahead of train.start_position_m "
                             f"{self.train.start_position_m} m")
        steps = self.bcu.step_decel_mps2 or [1.0]
        if self.bcu.stopping != "none" and self.bcu.stop_decel_mps2 > max(steps):
            raise ValueError(f"bcu.stop_decel_mps2 {self.bcu.stop_decel_mps2} is above the full service "
                             f"deceleration {max(steps)} m/s² (bcu.step_decel_mps2 step 7)")
        if self.becu.governor and self.plant.adhesion != "slip_speed":
            raise ValueError("becu.governor = true needs plant.adhesion = 'slip_speed' (the governor's "
                             "slip inclusion is built from that curve family)")
        if self.becu.governor and self.becu.slip_max_mps >= self.plant.slip_peak_mps:
            raise ValueError(f"becu.slip_max_mps {self.becu.slip_max_mps} must lie below the adhesion peak "
                             f"plant.slip_peak_mps {self.plant.slip_peak_mps} (stable-slip region)")
        return self
    faults: list[FaultSpec] = Field(default_factory=list)    # hil.scenario.faults; injected by hil.safety
    secoc: SecOcSpec = Field(default_factory=SecOcSpec)               # authentication keys
    # the studies that bring nodes of their own (hil.runtime.assembly.studies): absent = not part of this run
    preview: PreviewSpec | None = None        # seed 000: slip references with preview (hil/spec_preview.py)
    consensus: ConsensusSpec | None = None    # seed 003: consensus braking (hil/spec_consensus.py)
    acd: AcdSpec | None = None                # seed 002: anti-collision device (hil/spec_acd.py)

    @field_validator("desk")
    @classmethod
    def _sorted(cls, v):
        ts = [e.at_s for e in v]
        if ts != sorted(ts):
            raise ValueError(f"desk events must be in time order, got at_s {ts}")
        return v


def _describe(err: dict) -> str:
    loc = ".".join(str(p) for p in err["loc"]) or "(top level)"
    value = err.get("input")
    if err["type"] == "extra_forbidden":
        return f"key '{loc}' is not a scenario key{_closest_key(err['loc'])}"
    if err["type"] == "missing":
        return f"key '{loc}' is missing"
    shown = repr(value)
    if len(shown) > 60:
        shown = shown[:57] + "..."
    return f"key '{loc}' = {shown}: {err['msg']}"


def _closest_key(loc: tuple) -> str:
    """'; did you mean ...' for an unknown key at `loc`, from the fields of the model it sits in."""
    kind, inner = "model", Scenario
    for part in loc[:-1]:
        if kind == "model":
            field = inner.model_fields.get(str(part))
            if field is None:
                return ""
            kind, inner = _unwrap(field.annotation)
        elif kind in ("dict", "list"):       # part is a name or an index
            kind, inner = _unwrap(inner)
        else:
            return ""
    if kind != "model":
        return ""
    fields = list(inner.model_fields)
    close = difflib.get_close_matches(str(loc[-1]), fields, n=1, cutoff=0.5)
    prefix = ".".join(str(p) for p in loc[:-1])
    if close:
        return f"; did you mean '{prefix + '.' if prefix else ''}{close[0]}'?"
    return f"; valid keys here: {', '.join(fields)}"


def parse_scenario(data: dict, source: str = "<scenario>") -> Scenario:
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:
        errors = exc.errors()
        more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
        raise ScenarioError(f"{source}: {_describe(errors[0])}{more}") from None


# ------------------------------------------------------------------------------ --set KEY=VALUE overrides
def _unwrap(annotation):
    """The type behind Optional[...] / Annotated[...]: (kind, inner) with kind "model", "dict", "list" or
    "value"."""
    while True:
        origin = typing.get_origin(annotation)
        if origin is Annotated:
            annotation = typing.get_args(annotation)[0]
        elif origin in (typing.Union, types.UnionType):
            args = [a for a in typing.get_args(annotation) if a is not type(None)]
            if len(args) != 1:
                return "value", annotation
            annotation = args[0]
        else:
            break
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return "model", annotation
    if origin is dict:
        return "dict", typing.get_args(annotation)[1]
    if origin is list:
        return "list", typing.get_args(annotation)[0]
    return "value", annotation


def parse_set(text: str) -> tuple[str, object]:
    """`KEY=VALUE` of `railhil run --set`: the dotted scenario key and the value parsed as TOML
    (`true`, `0.25`, `"decel"`, `[0.0, 1.0]`); text that is not a TOML value is taken as a string, so
    `becu.control=decel` works without shell-quoted quotes."""
    key, sep, raw = text.partition("=")
    key, raw = key.strip(), raw.strip()
    if not sep or not key or not raw:
        raise ScenarioError(f"--set {text!r}: expected KEY=VALUE with a dotted scenario key, "
                            f"e.g. becu.governor=false")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return key, value


def apply_set(data: dict, key: str, value: object, source: str) -> None:
    """Put `value` at the dotted `key` of the raw scenario table `data` (in place), checking every part
    of the key against the Scenario model: an unknown key is a ScenarioError naming the closest valid
    one. Lists take an index (`desk.0.at_s`); dicts of models take any name (`nodes.BECU3.drift_ppm`).
    The value itself is validated with the whole scenario afterwards (parse_scenario)."""
    parts = key.split(".")
    kind, inner = "model", Scenario
    node: object = data
    for depth, part in enumerate(parts):
        here = ".".join(parts[:depth + 1])
        last = depth == len(parts) - 1
        if kind == "model":
            fields = inner.model_fields
            if part not in fields:
                close = difflib.get_close_matches(part, list(fields), n=1, cutoff=0.5)
                hint = (f"; did you mean '{'.'.join(parts[:depth] + close)}'?" if close
                        else f"; valid keys here: {', '.join(fields)}")
                raise ScenarioError(f"{source}: --set {key}: '{here}' is not a scenario key{hint}")
            kind, inner = _unwrap(fields[part].annotation)
        elif kind == "dict":
            kind, inner = _unwrap(inner)
        elif kind == "list":
            items = node
            if not part.isdigit() or not isinstance(items, list) or int(part) >= len(items):
                n = len(items) if isinstance(items, list) else 0
                raise ScenarioError(f"{source}: --set {key}: '{here}' needs an index below {n} of "
                                    f"the scenario's list '{'.'.join(parts[:depth])}'")
            if last:
                items[int(part)] = value
                return
            node = items[int(part)]
            kind, inner = _unwrap(inner)
            continue
        else:
            raise ScenarioError(f"{source}: --set {key}: '{'.'.join(parts[:depth])}' is a value, "
                                f"it has no key '{part}'")
        assert isinstance(node, dict)
        if last:
            node[part] = value
            return
        child = node.get(part)
        if child is None:
            child = node[part] = {} if kind in ("model", "dict") else []
        if kind in ("model", "dict") and not isinstance(child, dict):
            raise ScenarioError(f"{source}: --set {key}: '{here}' is not a table in the scenario")
        node = child


def load_scenario(path: str | Path, overrides: dict | None = None,
                  sets: list[str] | tuple[str, ...] = ()) -> Scenario:
    """Load and validate a scenario file. `overrides` replace top-level keys; `sets` are `railhil run
    --set KEY=VALUE` texts (dotted keys, TOML values) applied after them, in order."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ScenarioError(f"{path}: no such scenario file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"{path}: cannot read: {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML: {exc}") from None
    for key, value in (overrides or {}).items():
        data[key] = value
    set_keys = []
    for text in sets:
        key, value = parse_set(text)
        apply_set(data, key, value, str(path))
        set_keys.append(key)
    try:
        scenario = parse_scenario(data, str(path))
    except ScenarioError as exc:
        given = [k for k in set_keys if f"key '{k}'" in str(exc)]
        if given:
            raise ScenarioError(f"{exc} (given by --set {given[-1]}=...)") from None
        raise
    if scenario.dbc is not None:
        dbc_path = (path.parent / scenario.dbc).resolve()
        scenario = scenario.model_copy(update={"dbc": str(dbc_path)})
    ref = scenario.preview.rail_profile if scenario.preview is not None else None
    if ref and ("/" in ref or ref.endswith(".csv")) and not Path(ref).is_absolute() \
            and (path.parent / ref).is_file():        # a θ(x) table beside the scenario file
        preview = scenario.preview.model_copy(update={"rail_profile": str((path.parent / ref).resolve())})
        scenario = scenario.model_copy(update={"preview": preview})
    return scenario


def secoc_keys(scenario: Scenario) -> dict[str, bytes]:
    """Message name -> AES-128 key from the scenario's [secoc] section; "*" holds `key`, the key of
    every message not named (absent: the node runtime's development key)."""
    spec = scenario.secoc
    out = {name: bytes.fromhex(text) for name, text in spec.keys.items()}
    if spec.key is not None:
        out["*"] = bytes.fromhex(spec.key)
    return out

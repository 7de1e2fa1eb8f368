"""Scenario -> parameters: the one place a scenario becomes the frozen parameter sets of the plant and
the controllers.

`run_params(scenario)` builds them all once per run (`RunParams`): the plant's, the track, the BCU's and
each BECU's, the train's start in SI units (km/h -> m/s here and nowhere else: `mps`).  Every value comes
from plant_sim's or firmware_py's defaults unless the scenario says otherwise, so a scenario without a key
runs the foundation's train unchanged.  A study builds its own nodes' and stages' parameters
(hil/studies/<name>/scenario.py) from its section and the RunParams the core hands it.
"""

from __future__ import annotations

import dataclasses
import os
import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from firmware_py.bcu import BcuParams
from firmware_py.becu import BecuParams, Control, WspResume
from firmware_py.pi import PIParams
from firmware_py.reference_speed import RefMode
from firmware_py.wsp import WspMode
from hil.can.secoc import SecOcError, key_from_hex
from hil.resources import read_toml
from plant_sim.params import (  # G_MPS2: bar/g -> Pa per m/s² of seed 001's K_P, K_I (1 bar = 1e5 Pa)
    G_MPS2,
    AdhesionParams,
    BrakeParams,
    PadParams,
    PlantParams,
    SensorParams,
    TrainParams,
)
from plant_sim.track import Track

if TYPE_CHECKING:
    from hil.scenario.model import ScenarioBase as Scenario

KMH_PER_MPS = 3.6                   # km/h in one m/s


def build_track(scenario: Scenario) -> Track:
    """The track of [track]: rail conditions (segments or a θ(x) table), gradient and curves."""
    t = scenario.track
    gradient = [(g.from_m, g.permille) for g in t.gradient]
    curves = [(c.from_m, c.radius_m) for c in t.curves]
    if t.rail_table is not None:
        return Track.from_table([r.x_m for r in t.rail_table], [r.theta for r in t.rail_table],
                                gradient=gradient, curvature=curves)
    segments = [(s.from_m, s.condition if s.condition is not None else tuple(s.theta), s.transition_m)
                for s in t.rail]
    return Track.from_segments(segments, gradient=gradient, curvature=curves)


def pad_params(scenario: Scenario) -> PadParams | None:
    """The plant's variable pad friction (seed 004 eqs. (24)-(25)) when [plant] pad_friction = true."""
    ps = scenario.plant
    if not ps.pad_friction:
        return None
    kw: dict = {"initial_temp_rise_K": ps.disc_temp_rise_K}
    if ps.pad_speed_amplitude is not None:
        kw["n_v"] = ps.pad_speed_amplitude
    if ps.pad_cold_amplitude is not None:
        kw["n_T"] = ps.pad_cold_amplitude
    return PadParams(**kw)


def plant_params(scenario: Scenario) -> PlantParams:
    """PlantParams of a scenario: plant_sim's defaults, changed only where [train], [plant] or [sensors]
    say so."""
    t, ps, ss = scenario.train, scenario.plant, scenario.sensors
    train_kw: dict = {"masses_kg": t.masses()}
    if t.wheel_inertia_kgm2 is not None:
        train_kw["wheel_inertia_kgm2"] = t.wheel_inertia_kgm2
    if not t.running_resistance:
        train_kw.update(davis_c0_N=0.0, davis_c1_Ns_per_m=0.0, davis_c2_Ns2_per_m2=0.0,
                        davis_c2_lead_Ns2_per_m2=0.0)
    brake_kw: dict = {"pressure_model": ps.pressure_model, "tp_s": ps.tp_s}
    if ps.brake_gain_Nm_per_Pa is not None or ps.brake_preload_Pa is not None or ps.hysteresis_Pa is not None:
        d = BrakeParams()
        gain = d.alpha_squeeze_Nm_per_Pa if ps.brake_gain_Nm_per_Pa is None else ps.brake_gain_Nm_per_Pa
        preload = (-d.beta_squeeze_Nm / d.alpha_squeeze_Nm_per_Pa if ps.brake_preload_Pa is None
                   else ps.brake_preload_Pa)
        width = ((d.beta_release_Nm - d.beta_squeeze_Nm) / d.alpha_squeeze_Nm_per_Pa
                 if ps.hysteresis_Pa is None else ps.hysteresis_Pa)
        brake_kw.update(alpha_squeeze_Nm_per_Pa=gain, beta_squeeze_Nm=-gain * preload,   # eq. (6), seed 001
                        alpha_release_Nm_per_Pa=gain, beta_release_Nm=-gain * preload + gain * width)
    adhesion = (AdhesionParams(slip_speed_peak=(ps.mu_peak, ps.slip_peak_mps),
                               slip_speed_slide_ratio=ps.slide_ratio) if ps.adhesion == "slip_speed"
                else AdhesionParams())
    sensor_kw = {k: v for k, v in ss.model_dump().items() if v is not None}
    pp = PlantParams(train=TrainParams(**train_kw), brake=BrakeParams(**brake_kw), adhesion=adhesion,
                     sensors=SensorParams(**sensor_kw))
    pad = pad_params(scenario)
    return pp if pad is None else dataclasses.replace(pp, pad=pad)


def bcu_params(scenario: Scenario) -> BcuParams:
    """BcuParams: the scenario's [bcu] step table and jerk limit (the stages the studies fit into the BCU
    bring their own parameters: their nodes.py `bcu_stages`)."""
    kw: dict = {}
    if scenario.bcu.step_decel_mps2 is not None:
        kw["step_decel_mps2"] = tuple(scenario.bcu.step_decel_mps2)
    if scenario.bcu.jerk_limit_mps3 is not None:
        kw["jerk_limit_mps3"] = scenario.bcu.jerk_limit_mps3
    return BcuParams(**kw)


# slip-mode WSP: VENT -> HOLD below SLIP_WSP_HOLD of the vent threshold (the dump WSP's: 0.5): the vent stops
# as the wheel turns back, the pressure is held; HOLD -> FILL below SLIP_WSP_REFILL, as the dump WSP: refilled
# at 0.5, before the wheel was back, the slide never ended for the reference speed, whose spin-up rule then
# took the still slipping wheel for the car's speed (railhil wsp-test, extremely low adhesion) (chosen)
SLIP_WSP_HOLD = 0.8
SLIP_WSP_REFILL = 0.25


def becu_params(scenario: Scenario, car: int, pp: PlantParams) -> BecuParams:
    """BecuParams of car `car` (1-based) on the plant `pp`: the foundation's BECU unless [becu] says
    otherwise (the stages the studies fit into it bring their own parameters: their nodes.py
    `becu_stages`)."""
    b = scenario.becu
    d = BecuParams()
    kw: dict = {}
    if not (b.control == "pressure" and b.wsp_vent_slip_mps is None and b.wheel_trust_slip_mps is None):
        kw = {"control": Control(b.control), "car_mass_kg": pp.train.masses_kg[car - 1],
              "wsp_resume": WspResume(b.wsp_resume), "wheel_radius_m": pp.train.wheel_radius_m,
              "p_max_Pa": pp.brake.p_max_Pa}
        kw["decel_pi"] = PIParams(kp=b.kp_bar_per_g * 1e5 / G_MPS2, ki=b.ki_bar_per_g_s * 1e5 / G_MPS2,
                                  out_min=0.0, out_max=pp.brake.p_max_Pa)     # eq. (16), 0 ≤ u ≤ p̄ (5b)
        if b.wsp_vent_slip_mps is not None:                           # seed 001 §II-C: vent, then track
            kw["wsp"] = dataclasses.replace(
                d.wsp, vent_slip_mps=b.wsp_vent_slip_mps, vent_slip_per_speed=0.0,
                hold_fraction=b.wsp_refill_slip_mps / b.wsp_vent_slip_mps,
                refill_fraction=b.wsp_refill_slip_mps / b.wsp_vent_slip_mps)
        if b.wheel_trust_slip_mps == 0.0:                             # the scenario's word for seed
            kw["reference"] = RefMode.LIFTED                          # 001's accelerometer reference
        elif b.wheel_trust_slip_mps is not None:
            kw["wheel_trust_slip_mps"] = b.wheel_trust_slip_mps
    if b.wsp_mode == "slip":
        ceiling = {}                                                  # the ceiling's keys, if given
        if b.wsp_ceiling_fraction is not None:
            ceiling["ceiling_fraction"] = b.wsp_ceiling_fraction
        if b.wsp_ceiling_rise_bar_per_s is not None:
            ceiling["ceiling_rise_Pa_per_s"] = b.wsp_ceiling_rise_bar_per_s * 1e5
        if b.wsp_ceiling_release_s is not None:
            ceiling["ceiling_release_s"] = b.wsp_ceiling_release_s
        kw["wsp"] = dataclasses.replace(kw.get("wsp", d.wsp), mode=WspMode.SLIP, hold_fraction=SLIP_WSP_HOLD,
                                        refill_fraction=SLIP_WSP_REFILL, **ceiling)
    return BecuParams(**kw) if kw else d


@dataclass(frozen=True)
class RunParams:
    """Every parameter set of one run, built once from its scenario (`run_params`) and handed down: the
    plant's, its track, the BCU's and each BECU's, and the train's start in SI units."""

    plant: PlantParams
    track: Track
    bcu: BcuParams
    becus: tuple[BecuParams, ...]          # car 1 first
    initial_speed_mps: float               # [train] initial_speed_kmh
    start_position_m: float                # [train] start_position_m: car 1's centre at t = 0
    balises: tuple                         # [track] balises (plant_sim.track)
    seed: int

    def becu(self, car: int) -> BecuParams:
        """The BECU of car `car` (1-based)."""
        return self.becus[car - 1]


def mps(speed_kmh: float) -> float:
    """km/h -> m/s: the one conversion of a scenario's speeds."""
    return speed_kmh / KMH_PER_MPS


def kmh(speed_mps: float) -> float:
    """m/s -> km/h (a speed written back into a scenario key)."""
    return speed_mps * KMH_PER_MPS


_BUILT: dict[int, tuple[weakref.ref, RunParams]] = {}


def run_params(scenario: Scenario) -> RunParams:
    """The run's parameters, built on the first call for this scenario object and the same object after:
    a run builds each parameter set once, however many nodes, studies and reports ask."""
    hit = _BUILT.get(id(scenario))
    if hit is not None and hit[0]() is scenario:
        return hit[1]
    pp = plant_params(scenario)
    t = scenario.train
    built = RunParams(plant=pp, track=build_track(scenario), bcu=bcu_params(scenario),
                      becus=tuple(becu_params(scenario, car, pp) for car in range(1, t.cars + 1)),
                      initial_speed_mps=mps(t.initial_speed_kmh), start_position_m=t.start_position_m,
                      balises=tuple(scenario.track.balises), seed=scenario.seed)
    key = id(scenario)
    _BUILT[key] = (weakref.ref(scenario, lambda _, key=key: _BUILT.pop(key, None)), built)
    return built


KEY_ENV = "RAILHIL_SECOC_KEY"              # the key of every authenticated message, 32 hex digits
KEY_FILE_ENV = "RAILHIL_SECOC_KEY_FILE"     # a key file, when the scenario names none


def secoc_keys(scenario: Scenario) -> dict[str, bytes]:
    """Message name -> AES-128 key; "*" holds the key of every message not named (absent: the node
    runtime's development key).  Sources, each over the one before: $RAILHIL_SECOC_KEY (every message),
    the key file ([secoc] key_file, else $RAILHIL_SECOC_KEY_FILE; TOML with `key` and `[keys]`), the
    scenario's [secoc] `key` and `keys`.  A key that is not 32 hex digits, a key file that is missing or
    malformed, or no key at all under `require_key` is one SecOcError line naming where it looked."""
    spec = scenario.secoc
    out: dict[str, bytes] = {}
    env = os.environ.get(KEY_ENV)
    if env is not None:
        out["*"] = key_from_hex(env, f"environment variable {KEY_ENV}")
    file_from = "[secoc] key_file" if spec.key_file else f"${KEY_FILE_ENV}"
    key_file = spec.key_file or os.environ.get(KEY_FILE_ENV)
    if key_file:
        out.update(read_key_file(Path(key_file), file_from))
    if spec.key is not None:
        out["*"] = key_from_hex(spec.key, "[secoc] key")
    out.update({name: key_from_hex(text, f"[secoc] keys.{name}") for name, text in spec.keys.items()})
    if spec.require_key and "*" not in out:
        raise SecOcError(
            f"no SecOC key under [secoc] require_key: looked in [secoc] key of the scenario (none), the key "
            f"file ({key_file or f'none: no [secoc] key_file, ${KEY_FILE_ENV} not set'}) and ${KEY_ENV} "
            f"(not set){'; only per-message keys for ' + ', '.join(sorted(out)) if out else ''}")
    return out


def read_key_file(path: Path, named_by: str) -> dict[str, bytes]:
    """The keys of a key file: TOML, `key = "<32 hex digits>"` and/or `[keys] MESSAGE = "..."`."""
    where = f"SecOC key file {path} (from {named_by})"
    data = read_toml(path, SecOcError, where)
    unknown = sorted(set(data) - {"key", "keys"})
    if unknown:
        raise SecOcError(f"{where}: unknown entry {unknown[0]!r}; expected key = \"<32 hex digits>\" and/or "
                         "a [keys] table of MESSAGE = \"<32 hex digits>\"")
    keys = data.get("keys", {})
    if not isinstance(keys, dict):
        raise SecOcError(f"{where}: keys must be a table of MESSAGE = \"<32 hex digits>\"")
    out = {name: key_from_hex(text, f"{where}: keys.{name}") for name, text in keys.items()}
    if "key" in data:
        out["*"] = key_from_hex(data["key"], f"{where}: key")
    if not out:
        raise SecOcError(f"{where}: holds no key; expected key = \"<32 hex digits>\" and/or a [keys] table")
    return out

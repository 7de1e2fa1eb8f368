"""Seed 000 full mode: the BECU slip controller on the foundation's wheelset plant.

The reference generator of firmware_py.preview (Lf / Bd / Dp / ideal, oracle or estimated σ̄°) gives
Σ_i°.  The slip loop inverts the wheel's dynamics: with σ = 1 − rω/v and J ω̇ = μ N r − τ_b,
σ̇ = r (τ_b − μ N r)/(J v) + (1 − σ) v̇/v, so the brake torque

    τ_b = μ_meas N r + (J v / r) (α_c e + i − (1 − σ) v̇/v),   e = Σ_i° − σ_i,   i̇ = k_i e

asks for σ̇ = α_c (Σ_i° − σ_i) (eq. (4) with α = α_c) plus an integral term for what the model misses,
μ_meas being the adhesion the car's wheels use (its braking force over its weight) and v̇ car 1's
acceleration or, with accel_source = "own", the car's own accelerometer (which also feels its couplers).

The torque becomes a cylinder set-point in one of two ways (`SlipCtlParams.brake_inverse`):

* "direction" (the first version): the squeeze line τ = g_b (p − p_0) while the wanted torque rises, the
  release line τ = g_b (p − p_0 + w) while it falls (the brake's hysteresis, seed 001 eqs. (6), (10a)), led
  by Tp ṗ to cancel the "lag" cylinder (Tp = 50 ms, seed 001 §IV).  The line is guessed from the sign of the
  last change of the wanted torque, which flips with every small correction: the set-point then chatters
  across the 20 kPa band inside which the torque does not move at all, and the slip stalls.
* "model": the BECU runs a model of its cylinder (the lag of eq. (4)) and of the play operator (eq. (10a))
  on the set-points and WSP states it sent, so it knows the torque the brake gives now; `brake_setpoint`
  is then the exact inverse: the pressure on the line that leads from that torque to the wanted one (none
  if it is the same), led through the lag so that the cylinder gets there within `response_s`.

The foundation's wheel-slide protection (firmware_py.becu.wsp_transition) still vents above its slip
threshold and freezes the integral meanwhile.  The reference the loop tracks is capped at
(1 + above_own) times the optimum under the car's own wheels (see SlipCtlParams).  Eq. (4)'s α is
then what this loop achieves: hil measures it (hil.studies.preview_slip.reproduce.achieved_alpha).

Pure logic, no I/O, time passed in as integer µs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from firmware_py.constants import G_MPS2
from firmware_py.pi import PI, PIParams
from firmware_py.preview import EstimatorParams, PreviewBecu, RefParams, k2
from firmware_py.rx import RxTable
from firmware_py.wsp import Wsp, WspParams, wsp_transition


@dataclass(frozen=True)
class SlipCtlParams:
    """The slip loop and the car it brakes (hil fills the car from the plant's parameters)."""

    alpha_c_per_s: float = 5.0         # α_c: the slip dynamics the loop asks for [1/s] (chosen: 1/α_c = 4 Tp)
    ki_per_s2: float = 1.0             # k_i of the integral term [1/s²] (chosen)
    mass_kg: float = 40_000.0          # car mass: N = m g [kg]
    g_mps2: float = G_MPS2
    wheel_radius_m: float = 0.46       # r [m]
    inertia_kgm2: float = 600.0        # J of the car's lumped wheelset [kg m²]
    brake_gain_Nm_per_Pa: float = 0.08 # g_b of the squeeze line τ = g_b (p − p_0), seed 001 eq. (6)
    preload_Pa: float = 30e3           # p_0 [Pa]
    p_max_Pa: float = 450e3            # p̄ [Pa]
    tp_s: float = 0.05                 # Tp of the lag cylinder [s]: the set-point leads by Tp ṗ (its inverse)
    hysteresis_Pa: float = 20e3        # w: the release line lies w above the squeeze line, seed 001 eq. (6)
    # the loop tracks at most (1 + above_own) times the optimum under the car's own wheels (chosen; None: no
    # cap, the reference as generated): a preview that asks for more slip than the rail under the wheel can
    # take puts the wheel past its adhesion peak, where it is unstable. With the "direction" inverse that
    # slid into WSP venting; the "model" inverse holds it (hil/studies/preview_slip/nodes.py runs it without
    # the cap)
    above_own: float | None = 0.1
    wsp: WspParams = field(default_factory=WspParams)
    cycle_us: int = 10_000
    # How the torque is turned into a cylinder set-point (see `brake_setpoint`):
    # "direction": the line is chosen by the direction the wanted torque moves, plus the lead Tp ṗ;
    # "model": an internal model of the lag cylinder and of the play operator (seed 001 eqs. (4), (10a))
    # tracks the torque the brake gives; the set-point is the pressure on the line that reaches the wanted
    # torque from there, led so that the cylinder gets there within `response_s`
    brake_inverse: str = "direction"
    response_s: float = 0.02           # "model": time given to the cylinder to get there [s] (chosen)
    setpoint_quantum_Pa: float = 1000.0  # resolution of CylPressureSet in the DBC [Pa]
    # v̇ in σ̇'s (1 − σ) v̇/v term: "train" = car 1's (PLANT_TRAIN.Accel), "own" = the car's own
    # accelerometer (PLANT_CARi_SENSORS.AccelLong), which also sees its coupler's pushes and pulls
    accel_source: str = "train"

    def __post_init__(self) -> None:
        if self.brake_inverse not in ("direction", "model"):
            raise ValueError(f"SlipCtlParams.brake_inverse must be 'direction' or 'model', "
                             f"got {self.brake_inverse!r}")
        if self.accel_source not in ("train", "own"):
            raise ValueError(f"SlipCtlParams.accel_source must be 'train' or 'own', "
                             f"got {self.accel_source!r}")


def play_torque(tau_prev_Nm: float, p_Pa: float, q: SlipCtlParams) -> float:
    """Brake torque [N m] after the cylinder moved monotonically to p [Pa] from a state with torque
    tau_prev: the play operator of seed 001 eq. (10a) between the squeeze line g_b (p − p_0) and the
    release line g_b (p − p_0 + w) (the BECU's model of plant_sim.brake.hysteresis_torque_scalar)."""
    squeeze = q.brake_gain_Nm_per_Pa * (p_Pa - q.preload_Pa)
    release = squeeze + q.brake_gain_Nm_per_Pa * q.hysteresis_Pa
    tau = max(tau_prev_Nm, squeeze)                 # pressure rose past the squeeze line: torque on it
    return max(min(tau, release), 0.0)              # fell past the release line: on it; never < 0


def brake_setpoint(tau_want_Nm: float, tau_now_Nm: float, p_now_Pa: float, dt_s: float,
                   q: SlipCtlParams) -> float:
    """Cylinder set-point [Pa] that gives the torque tau_want [N m], from a brake at pressure p_now [Pa]
    with torque tau_now: the pressure on the squeeze line if the torque must rise, on the release line if it
    must fall, none if it stays (the exact inverse of the play operator); then led through the lag
    cylinder ṗ = (u − p)/Tp so that p gets there within response_s (u = p + (p* − p)/(1 − e^{−T/Tp}),
    T = max(response_s, dt)); clipped to [0, p̄]."""
    g = q.brake_gain_Nm_per_Pa
    if tau_want_Nm > tau_now_Nm:
        target = tau_want_Nm / g + q.preload_Pa                       # on the squeeze line
    elif tau_want_Nm < tau_now_Nm:
        target = max(tau_want_Nm, 0.0) / g + q.preload_Pa - q.hysteresis_Pa   # on the release line
    else:
        target = p_now_Pa
    reach = 1.0 - math.exp(-max(q.response_s, dt_s) / q.tp_s)        # share of a step the lag covers
    return min(max(p_now_Pa + (target - p_now_Pa) / reach, 0.0), q.p_max_Pa)


class SlipBecu:
    """BECU i in full mode: `PreviewBecu` for Σ_i°, plus the slip PI and WSP on BECUi_PRESS_CMD."""

    def __init__(self, ref: RefParams, n_cars: int, source: str = "oracle",
                 estimator: EstimatorParams | None = None, p: SlipCtlParams | None = None) -> None:
        self.p = p or SlipCtlParams()
        self.gen = PreviewBecu(ref, n_cars, source, estimator)
        i = ref.car
        self.inputs = self.gen.inputs
        cmd = f"BECU{i}_PRESS_CMD"
        self.k_pressure_set, self.k_valve_cmd, self.k_wsp_valve = (f"{cmd}.CylPressureSet", f"{cmd}.ValveCmd",
                                                                   f"{cmd}.WspValve")
        self.OUTPUTS = self.gen.OUTPUTS + (self.k_pressure_set, self.k_valve_cmd, self.k_wsp_valve)
        q = self.p
        self.pi = PI(PIParams(kp=q.alpha_c_per_s, ki=q.ki_per_s2, out_min=-50.0, out_max=50.0))  # σ̇ [1/s]
        self.pressure = 0.0
        self._p_des: float | None = None
        self._releasing = False
        self.wsp = Wsp.FILL
        self._slip_key = f"PLANT_CAR{i}_ADH.Slip"
        self._mu_key = f"PLANT_CAR{i}_ADH.AdhesionUsed"
        self._last_us: int | None = None
        self._accel_key = f"PLANT_CAR{i}_SENSORS.AccelLong"
        if self.p.accel_source == "own":
            self.inputs = self.inputs + (self._accel_key,)
        self.p_model = 0.0              # "model": the cylinder pressure the BECU expects [Pa]
        self.tau_model = 0.0            # "model": the brake torque the BECU expects [N m]
        self._u_applied = 0.0           # set-point sent last cycle [Pa]
        self._wsp_applied = Wsp.FILL    # WSP state sent last cycle

    def _advance_model(self, dt_s: float) -> None:
        """The internal cylinder/brake model over the last cycle, with what was sent: the lag cylinder
        (seed 001 eq. (4), Tp) towards the set-point, held by WSP HOLD, vented (u = 0) by WSP VENT, then the
        play operator (eq. (10a)) at the new pressure (exact: the pressure moves monotonically)."""
        q = self.p
        if self._wsp_applied != Wsp.HOLD:
            u = 0.0 if self._wsp_applied == Wsp.VENT else self._u_applied
            self.p_model = u + (self.p_model - u) * math.exp(-dt_s / q.tp_s)      # eq. (4), seed 001
        self.tau_model = play_torque(self.tau_model, self.p_model, q)           # eq. (10a), seed 001

    def step(self, now_us: int, rx: RxTable) -> dict[str, float]:
        out = dict(self.gen.step(now_us, rx))
        dt = self.p.cycle_us * 1e-6 if self._last_us is None else (now_us - self._last_us) * 1e-6
        self._last_us = now_us
        if self.p.brake_inverse == "model":
            self._advance_model(dt)
        sigma, mu, v = rx[self._slip_key], rx[self._mu_key], rx["PLANT_TRAIN.Speed"]
        q = self.p
        gen = self.gen
        own = out[gen.k_sigma_bar] / k2(v if math.isfinite(v) else 0.0, gen.p.pi2_s_per_m)
        ref = out[gen.k_slip_ref]
        if out[gen.k_valid] and q.above_own is not None:
            ref = min(ref, (1.0 + q.above_own) * own)
        if math.isfinite(sigma) and math.isfinite(v) and math.isfinite(mu):
            self.wsp = wsp_transition(self.wsp, sigma * v, v, q.wsp)            # slip speed s = σ v
            rate = self.pi.update(ref - sigma, dt, freeze=self.wsp != Wsp.FILL)   # desired σ̇ [1/s]
            r, vv = q.wheel_radius_m, max(v, 0.5)
            accel = rx[self._accel_key] if q.accel_source == "own" else rx["PLANT_TRAIN.Accel"]
            rate -= (1.0 - sigma) * (accel if math.isfinite(accel) else 0.0) / vv      # the v̇ term of σ̇
            torque = mu * q.mass_kg * q.g_mps2 * r + q.inertia_kgm2 * vv / r * rate
            if q.brake_inverse == "model":
                u = brake_setpoint(torque, self.tau_model, self.p_model, dt, q)
                quantum = q.setpoint_quantum_Pa
                self.pressure = round(u / quantum) * quantum                # as the DBC sends it
                self._u_applied, self._wsp_applied = self.pressure, self.wsp
                out[self.k_pressure_set] = self.pressure
                out[self.k_valve_cmd] = 1.0
                out[self.k_wsp_valve] = int(self.wsp)
                return out
            p_des = torque / q.brake_gain_Nm_per_Pa + q.preload_Pa                  # on the squeeze line
            lead = 0.0 if self._p_des is None or dt <= 0.0 else q.tp_s * (p_des - self._p_des) / dt
            if self._p_des is not None and p_des != self._p_des:
                self._releasing = p_des < self._p_des                   # which line the torque moves on
            self._p_des = p_des
            release = q.hysteresis_Pa if self._releasing else 0.0
            self.pressure = min(max(p_des + lead - release, 0.0), q.p_max_Pa)
        out[self.k_pressure_set] = self.pressure        # nothing measured yet: 0, then the last value
        out[self.k_valve_cmd] = 1.0
        out[self.k_wsp_valve] = int(self.wsp)
        return out

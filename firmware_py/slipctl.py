"""Seed 000 full mode: the BECU slip controller on the foundation's wheelset plant.

The reference generator of firmware_py.preview (Lf / Bd / Dp / ideal, oracle or estimated σ̄°) gives
Σ_i°.  The slip loop inverts the wheel's dynamics: with σ = 1 − rω/v and J ω̇ = μ N r − τ_b,
σ̇ = r (τ_b − μ N r)/(J v) + (1 − σ) v̇/v, so the brake torque

    τ_b = μ_meas N r + (J v / r) (α_c e + i − (1 − σ) v̇/v),   e = Σ_i° − σ_i,   i̇ = k_i e

asks for σ̇ = α_c (Σ_i° − σ_i) (eq. (4) with α = α_c) plus an integral term for what the model misses,
μ_meas being the adhesion the car's wheels use (its braking force over its weight).  The pressure
set-point follows from the brake's squeeze line τ = g_b (p − p_0) while the torque must rise, and from
the release line τ = g_b (p − p_0 + w) while it must fall (the inverse of the brake's hysteresis, seed
001 eqs. (6), (10a)), led by Tp ṗ to cancel the plant's "lag" cylinder (Tp = 50 ms, seed 001 §IV).
The foundation's wheel-slide protection (firmware_py.becu.wsp_transition) still vents above its slip
threshold and freezes the integral meanwhile.  The reference the loop tracks is capped at
(1 + above_own) times the optimum under the car's own wheels (see SlipCtlParams).  Eq. (4)'s α is
then what this loop achieves: hil measures it (hil.picasso.achieved_alpha).

Pure logic, no I/O, time passed in as integer µs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from firmware_py.becu import Wsp, WspParams, wsp_transition
from firmware_py.pi import PI, PIParams
from firmware_py.preview import EstimatorParams, PreviewBecu, RefParams, k2


@dataclass(frozen=True)
class SlipCtlParams:
    """The slip loop and the car it brakes (hil fills the car from the plant's parameters)."""

    alpha_c_per_s: float = 5.0         # α_c: the slip dynamics the loop asks for [1/s] (chosen: 1/α_c = 4 Tp)
    ki_per_s2: float = 1.0             # k_i of the integral term [1/s²] (chosen)
    mass_kg: float = 40_000.0          # car mass: N = m g [kg]
    g_mps2: float = 9.81
    wheel_radius_m: float = 0.46       # r [m]
    inertia_kgm2: float = 600.0        # J of the car's lumped wheelset [kg m²]
    brake_gain_Nm_per_Pa: float = 0.08 # g_b of the squeeze line τ = g_b (p − p_0), seed 001 eq. (6)
    preload_Pa: float = 30e3           # p_0 [Pa]
    p_max_Pa: float = 450e3            # p̄ [Pa]
    tp_s: float = 0.05                 # Tp of the lag cylinder [s]: the set-point leads by Tp ṗ (its inverse)
    hysteresis_Pa: float = 20e3        # w: the release line lies w above the squeeze line, seed 001 eq. (6)
    # the loop tracks at most (1 + above_own) times the optimum under the car's own wheels (chosen): a
    # preview that asks for more slip than the rail under the wheel can take would put the wheel past its
    # adhesion peak, where it is unstable and slides into WSP venting (paper mode has no such instability)
    above_own: float = 0.1
    wsp: WspParams = field(default_factory=WspParams)
    cycle_us: int = 10_000


class SlipBecu:
    """BECU i in full mode: `PreviewBecu` for Σ_i°, plus the slip PI and WSP on BECUi_PRESS_CMD."""

    def __init__(self, ref: RefParams, n_cars: int, source: str = "oracle",
                 estimator: EstimatorParams | None = None, p: SlipCtlParams | None = None) -> None:
        self.p = p or SlipCtlParams()
        self.gen = PreviewBecu(ref, n_cars, source, estimator)
        i = ref.car
        self.inputs = self.gen.inputs
        self._press = (f"BECU{i}_PRESS_CMD.CylPressureSet", f"BECU{i}_PRESS_CMD.ValveCmd",
                       f"BECU{i}_PRESS_CMD.WspValve")
        self.OUTPUTS = self.gen.OUTPUTS + self._press
        q = self.p
        self.pi = PI(PIParams(kp=q.alpha_c_per_s, ki=q.ki_per_s2, out_min=-50.0, out_max=50.0))  # σ̇ [1/s]
        self.pressure = 0.0
        self._p_des: float | None = None
        self._releasing = False
        self.wsp = Wsp.FILL
        self._ref_key = self.gen.OUTPUTS[0]
        self._slip_key = f"PV_PLANT_CAR{i}_ADH.Slip"
        self._mu_key = f"PV_PLANT_CAR{i}_ADH.AdhesionUsed"
        self._own_key, self._valid_key = f"PV_BECU{i}_PREVIEW.SigmaOptBar", f"PV_BECU{i}_PREVIEW.Valid"
        self._last_us: int | None = None

    def step(self, now_us: int, rx) -> dict[str, float]:
        out = dict(self.gen.step(now_us, rx))
        dt = self.p.cycle_us * 1e-6 if self._last_us is None else (now_us - self._last_us) * 1e-6
        self._last_us = now_us
        sigma, mu, v = rx[self._slip_key], rx[self._mu_key], rx["PV_PLANT_TRAIN.Speed"]
        q = self.p
        own = out[self._own_key] / k2(v if math.isfinite(v) else 0.0, self.gen.p.pi2_s_per_m)
        ref = out[self._ref_key]
        if out[self._valid_key]:
            ref = min(ref, (1.0 + q.above_own) * own)
        if math.isfinite(sigma) and math.isfinite(v) and math.isfinite(mu):
            self.wsp = wsp_transition(self.wsp, sigma * v, v, q.wsp)            # slip speed s = σ v
            rate = self.pi.update(ref - sigma, dt, freeze=self.wsp != Wsp.FILL)   # desired σ̇ [1/s]
            r, vv = q.wheel_radius_m, max(v, 0.5)
            accel = rx["PV_PLANT_TRAIN.Accel"]
            rate -= (1.0 - sigma) * (accel if math.isfinite(accel) else 0.0) / vv      # the v̇ term of σ̇
            torque = mu * q.mass_kg * q.g_mps2 * r + q.inertia_kgm2 * vv / r * rate
            p_des = torque / q.brake_gain_Nm_per_Pa + q.preload_Pa                  # on the squeeze line
            lead = 0.0 if self._p_des is None or dt <= 0.0 else q.tp_s * (p_des - self._p_des) / dt
            if self._p_des is not None and p_des != self._p_des:
                self._releasing = p_des < self._p_des                   # which line the torque moves on
            self._p_des = p_des
            release = q.hysteresis_Pa if self._releasing else 0.0
            self.pressure = min(max(p_des + lead - release, 0.0), q.p_max_Pa)
        out[self._press[0]] = self.pressure             # nothing measured yet: 0, then the last value
        out[self._press[1]] = 1.0
        out[self._press[2]] = int(self.wsp)
        return out

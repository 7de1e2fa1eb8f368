"""The one PI primitive every loop in railhil uses (pressure, deceleration, precise stop).

Modelled on openpilot's common/pid.py::PIDController and simple-pid's set_auto_mode(): conditional
anti-windup (the integrator does not move further into a saturated output), an explicit integrator
freeze (e.g. while wheel-slide protection overrides the actuator), and bumpless hand-over (the
integrator is set so that the first output after hand-over equals the last applied one).
"""

from __future__ import annotations

from dataclasses import dataclass

from numba.extending import register_jitable

from firmware_py.limits import clip


@dataclass(frozen=True)
class PIParams:
    kp: float        # proportional gain [output unit / error unit]
    ki: float        # integral gain [output unit / (error unit * s)]
    out_min: float   # output saturation, lower [output unit]
    out_max: float   # output saturation, upper [output unit]


def pi_step(p: PIParams, i: float, error: float, dt_s: float, feedforward: float = 0.0,
            freeze: bool = False) -> tuple[float, float, bool]:
    """One PI update as a pure function: (output, next integrator, saturated).

    u = clip(ff + kp·e + i⁺) with i⁺ = i + ki·e·dt, except that i is kept when frozen or when the
    unclipped output is beyond a limit and the error pushes further into it (conditional anti-windup).
    `PI.update` is this function plus the stored state; predictions (firmware_py.governor) run it, as
    `pi_step_scalar`, so the controller and its model are one implementation.
    """
    return pi_step_scalar(p.kp, p.ki, p.out_min, p.out_max, i, error, dt_s, feedforward, freeze)


@register_jitable
def pi_step_scalar(kp: float, ki: float, out_min: float, out_max: float, i: float, error: float, dt_s: float,
                   feedforward: float, freeze: bool) -> tuple[float, float, bool]:
    """`pi_step` on plain numbers: plain Python when called from Python, compiled into the governor's
    prediction (firmware_py.governor)."""
    i_next = i if freeze else i + ki * error * dt_s
    unclipped = feedforward + kp * error + i_next
    out = clip(unclipped, out_min, out_max)
    # conditional anti-windup: keep the old integrator when it would push further into the limit
    winding_up = (unclipped > out_max and error > 0.0) or (unclipped < out_min and error < 0.0)
    return out, (i if winding_up else i_next), unclipped != out


class PI:
    """u = ff + kp*e + i,  i += ki*e*dt  unless frozen or winding up into saturation."""

    def __init__(self, params: PIParams) -> None:
        self.p = params
        self.i = 0.0
        self.saturated = False
        self.frozen = False
        self.output = 0.0

    def reset(self, i: float = 0.0) -> None:
        self.i = i
        self.saturated = False

    def handover(self, last_output: float, error: float = 0.0, feedforward: float = 0.0) -> None:
        """Bumpless transfer: the next update with this error returns `last_output`."""
        self.i = clip(last_output, self.p.out_min, self.p.out_max) - feedforward - self.p.kp * error
        self.output = last_output

    def update(self, error: float, dt_s: float, feedforward: float = 0.0, freeze: bool = False) -> float:
        self.frozen = freeze
        out, self.i, self.saturated = pi_step(self.p, self.i, error, dt_s, feedforward, freeze)
        self.output = out
        return out

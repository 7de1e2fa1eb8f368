"""The one PI primitive every loop in railhil uses (pressure, deceleration, precise stop).

Modelled on openpilot's common/pid.py::PIDController and simple-pid's set_auto_mode(): conditional
anti-windup (the integrator does not move further into a saturated output), an explicit integrator
freeze (e.g. while wheel-slide protection overrides the actuator), and bumpless hand-over (the
integrator is set so that the first output after hand-over equals the last applied one).
"""

from __future__ import annotations

from dataclasses import dataclass

from firmware_py.governor_kernel import clip, pi_step_scalar


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
    `PI.update` is this function plus the stored state.  The equations are
    `firmware_py.governor_kernel.pi_step_scalar`, which the governor's compiled prediction runs too
    (firmware_py.governor): the controller and its model are one implementation.
    """
    return pi_step_scalar(p.kp, p.ki, p.out_min, p.out_max, i, error, dt_s, feedforward, freeze)


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

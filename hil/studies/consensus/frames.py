"""The frames of the consensus-braking study (seed 003).

Part of dbc/generator/train_brake.py (run that script to write the DBC).  Identifiers: 0x058-0x06F.

Per cycle of the consensus loop each car puts two frames on the bus: its sensor frame (PLANT -> its
BECU: speed and displacement) and its BECU's frame (force command to the PLANT, and the car's speed and
displacement for the other BECUs: the complete graph of velocities, eq. (6), and the path graph of
displacements, eq. (7), seed 003).  Commands have lower identifiers than sensor frames, so a BECU's
command overtakes the sensor frames still queued.  The study supports up to CONS_MAX_CARS cars (three
identifiers per car and one for the virtual leader fill 0x058-0x06D).
"""

from __future__ import annotations

from hil.can.dbcschema import Extra, Msg, Sig, becus, e2e  # noqa: F401

CONS_MAX_CARS = 7
POSITION_WRAP_M = 419.4304   # 2**22 × 0.1 mm: Position signals carry x modulo this
#: cycle of the consensus loop [ms]: sensor frames and BECU frames.  The slowest cycle at which the
#: ±1 cm coupler band of seed 003 still holds on the bit-timed bus (`railhil reproduce consensus`, cycle
#: sweep: 2 ms on the consensus loop's own 1 Mbit/s segment, 73 % load; the rest of the train keeps the
#: DBC's 500 kbit/s, where 12 frames of a 2 ms cycle do not fit)
CONS_CYCLE_MS = 2
REF_CYCLE_MS = 10        # virtual leader v*(t): a ramp the BECUs extrapolate between frames
#: diagnostics for the trace (observer estimate, terms of the law).  Not in the loop: their identifiers are
#: the lowest priority, so they go after the loop's frames (6 % of the 1 Mbit/s bus; at 50 ms the couplers
#: move the same, to 0.01 mm)
DIAG_CYCLE_MS = 10

REF_ID = 0x058
CONS_ID = 0x058          # + car (0x059-0x05F)
SENSE_ID = 0x05F         # + car (0x060-0x066)
DIAG_ID = 0x066          # + car (0x067-0x06D)


def messages() -> list[Msg]:
    n = CONS_MAX_CARS
    cars = becus(n)
    msgs = [
        Msg(REF_ID, "CONS_REF", "BCU", cars, REF_CYCLE_MS,
            "Seed 003 virtual leader: the desired braking curve v*(t) = v*(t0) - a* t (eq. 9) from the BCU.",
            [
                Sig("VRef", 0, 16, scale=0.001, maximum=65.535, unit="m/s",
                    comment="desired speed v*(t) at the time of sending (eq. 9, seed 003)"),
                Sig("ARef", 16, 12, scale=0.001, maximum=4.095, unit="m/s^2",
                    comment="desired deceleration a* of the curve; receivers extrapolate v* with it"),
                Sig("Active", 28, 1, maximum=1, comment="1 = consensus braking to the curve is commanded"),
            ], dlc=4),
    ]
    for i in range(1, n + 1):
        msgs.append(Msg(
            CONS_ID + i, f"BECU{i}_CONS", f"BECU{i}", ["PLANT"] + [b for b in cars if b != f"BECU{i}"],
            CONS_CYCLE_MS,
            f"Car {i}: consensus braking (seed 003): force command u_i (eqs. 24-29) and the car's speed and "
            f"displacement for the other BECUs (graphs of eqs. 6-7).",
            [
                Sig("ForceCmd", 0, 16, scale=250.0, minimum=-8192000.0, maximum=8191750.0, unit="N",
                    signed=True, comment="braking force command K_b u_i (+ brakes), eq. 3 seed 003"),
                Sig("Speed", 16, 16, scale=0.001, maximum=65.535, unit="m/s",
                    comment="car speed v_i the BECU measured (its sensor frame)"),
                Sig("Position", 32, 22, scale=0.0001, maximum=419.4303, unit="m",
                    comment="car displacement x_i the BECU measured (its sensor frame), modulo 419.4304 m"),
                Sig("Sample", 54, 4, maximum=15,
                    comment="Sample of the sensor frame Speed and Position come from (receivers align "
                            "positions sampled in different cycles with it)"),
                Sig("ObserverOn", 58, 1, maximum=1,
                    comment="1 = the sliding-mode observer's estimate is compensated (eq. 29)"),
                Sig("BarrierSat", 59, 1, maximum=1,
                    comment="1 = the potential-field term (eq. 27) is at its saturation"),
                Sig("InputMissing", 60, 1, maximum=1,
                    comment="1 = a speed, neighbour displacement or the virtual leader is missing or stale"),
            ]))
    for i in range(1, n + 1):
        msgs.append(Msg(
            SENSE_ID + i, f"PLANT_CONS_CAR{i}", "PLANT", [f"BECU{i}"], CONS_CYCLE_MS,
            f"Car {i}: speed and displacement sensors of the seed-003 plant (odometer), to BECU{i}.",
            [
                Sig("Speed", 0, 16, scale=0.001, maximum=65.535, unit="m/s", comment="car speed v_i"),
                Sig("Position", 16, 22, scale=0.0001, maximum=419.4303, unit="m",
                    comment="car displacement x_i (centre of the car, + forwards) modulo 419.4304 m: the "
                            "counter wraps, receivers use differences"),
                Sig("Sample", 38, 4, maximum=15,
                    comment="sample counter mod 16, +1 per frame: every car's frame of one cycle has the "
                            "same value (the plant samples all cars at once)"),
            ], dlc=6))
    for i in range(1, n + 1):
        msgs.append(Msg(
            DIAG_ID + i, f"BECU{i}_CONS_DIAG", f"BECU{i}", ["BCU"], DIAG_CYCLE_MS,
            f"Car {i}: consensus-braking diagnostics of BECU{i} (seed 003), per unit mass.",
            [
                Sig("PhiHat", 0, 16, scale=0.0005, minimum=-16.384, maximum=16.3835, unit="m/s^2",
                    signed=True, comment="sliding-mode observer estimate of phi_i/m_i (eqs. 11, 22)"),
                Sig("ConsensusAccel", 16, 16, scale=0.01, minimum=-327.68, maximum=327.67, unit="m/s^2",
                    signed=True, comment="consensus term u_i1/m_i (eq. 25)"),
                Sig("PotentialAccel", 32, 16, scale=0.01, minimum=-327.68, maximum=327.67, unit="m/s^2",
                    signed=True, comment="potential-field term u_i2/m_i (eq. 27)"),
                Sig("SpeedError", 48, 16, scale=0.001, minimum=-32.768, maximum=32.767, unit="m/s",
                    signed=True, comment="tracking error v_ei = v_i - v*(t)"),
            ]))
    return msgs


def signals() -> list[Extra]:
    """This study adds no signal to the foundation's frames."""
    return []

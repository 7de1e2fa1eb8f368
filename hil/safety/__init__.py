"""Safety: fault injection (EN 50159 threats, babbling, bus-off, stuck signals, failed sensors) and the
threat matrix that runs every threat against every protected frame.

- `injection`     the injector the lockstep bus, the nodes and the plant apply
- `threat_matrix` one lockstep run per cell (threat x protected frame, sender bus-off, babbling), judged
                  on detection and plant truth, per scenario family
- `matrix_report` the matrix as a table: matrix.md and matrix.json
"""

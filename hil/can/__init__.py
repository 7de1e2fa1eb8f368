"""The CAN layer: the DBC, the codec, AUTOSAR E2E and SecOC protection, and the bus's timing.

- `dbc`       loading the DBC (the single source of truth), name lookup with suggestions
- `codec`     per-message encode/decode, proven equal to cantools
- `e2e`       AUTOSAR E2E profiles 1 and 2 (counter + CRC)
- `secoc`     AUTOSAR SecOC profile 1 (AES-CMAC, freshness)
- `attributes` what the DBC's attributes say of a message: its E2E and SecOC, the signals its node fills
- `busload`   frame lengths and the static bus load of a DBC
- `bustiming` the bit-timed lockstep bus: durations, arbitration, transmit queues
- `stuffing`  CRC-15 and bit stuffing of a frame's bits, the tables and their numba kernel (bustiming's)
- `rta`       worst-case response-time analysis (Davis et al. 2007)
"""

"""The plant's links beyond CAN: GPS over a serial line and the control centre over TCP.

- `nmea`           NMEA 0183 RMC/GGA and the compact binary GPS protocol
- `gpsserial`      the GPS serial line through pyserial (loop:// in lockstep, a pty in real time)
- `control_centre` the control centre of the anti-collision algorithm: TCP service, SQLite
"""

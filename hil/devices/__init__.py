"""What the user brings: a device on its own CAN matrix, mapped onto the bench.

A device description (a TOML file, `description`) names the bench node the device replaces, the device's
own DBC, the bus it sits on, the protection of its frames, and the map between its signals and the bench's
(`mapping`: units through pint, scale and offset, value tables, a default while a source is stale).
`device.load_device` checks all of it against both DBCs and gives a `Device`; `gateway.Gateway` is the
bench side of it: a node like any other on the bench's bus (its frames carry the bench's E2E and SecOC)
and, on the device's bus, the frames the device receives, with the device's own protection.  The same
gateway runs in lockstep, with the device's model (`model`) on a bus of its own, and in real time, between
the bench's python-can bus and the device's (hil.runtime hosts it in either mode).
"""

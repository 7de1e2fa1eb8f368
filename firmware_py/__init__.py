"""The brake controllers: what would be flashed on the ECUs.

Pure logic: no I/O, no clock (time is passed in as integer microseconds), no imports from `hil` or
`plant_sim`.  A controller is a class with `step(now_us, rx) -> dict` of output signals, `rx` the
receive table of its inputs with their reception times (`firmware_py.rx.RxTable`); mode logic is a pure
transition function.
"""

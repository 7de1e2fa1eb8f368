"""railhil: a hardware-in-the-loop testbench for railway brake electronics over CAN.

The controllers are firmware_py's, the physics plant_sim's; this package is everything between, in
wings: can (the DBC, codec, E2E, SecOC, bus timing), trace (reading and analysing traces), scenario
(the model, loading, scenario -> parameters, the study registry), links (GPS serial line, control
centre), runtime (nodes, lockstep and real-time runners, one run), safety (fault injection, the threat
matrix), report (KPIs, plots, HTML), campaign (sweeps), studies (one folder per study) and cli
(`railhil`).  docs/architecture.md describes the layers.
"""

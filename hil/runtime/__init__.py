"""Running nodes: the node runtime, release timing, the lockstep and real-time runners, one run.

- `node`       binds a controller to DBC messages: decoding, E2E/SecOC checks, encoding
- `plant_node` the PLANT node: plant_sim on the bus, and the ground truth it records
- `desk`       the DESK node: the scenario's command timeline
- `assembly`   which nodes a scenario has and how each is built (the studies add theirs)
- `release`    cycle phase, drift, jitter and message delays in lockstep
- `lockstep`   one process, simulated time, the bit-timed bus: deterministic
- `realtime`   OS processes on a python-can bus, wall-clock time
- `clock`      the run's clock: simulated = (t − t0) · speed, on the monotonic and the trace's clock
- `outcome`    what a run produced, in either mode, and whether it held real time
- `run`        one run of a scenario and the run folder it leaves: the trace, truth.csv, run.json
- `truth`      the plant's ground truth in the folder (truth.csv), and when the train stands
- `provenance` what reproduces a run: versions, the DBC's SHA-256, the git commit

The runtime imports neither the report nor safety: the report reads the run folder it leaves
(hil.report.run), and a lockstep run's caller hands in the fault injector (hil.runtime.lockstep.FaultHook).
"""

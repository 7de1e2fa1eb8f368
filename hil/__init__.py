"""railhil: a hardware-in-the-loop testbench for railway brake electronics over CAN.

The controllers are firmware_py's, the physics plant_sim's; this package is everything between, in
wings: can (the DBC, codec, E2E, SecOC, bus timing), trace (reading, writing, decoding and analysing
traces), scenario (the model, loading, scenario -> parameters, the study registry), links (GPS serial
line, control centre), runtime (nodes, lockstep and real-time runners, one run), safety (fault
injection, the threat matrix), report (KPIs, plots, HTML, run folders in Python), campaign (sweeps),
studies (one folder per study) and cli (`railhil`).  docs/architecture.md describes the layers.

In a notebook: `hil.open_run(RUN_FOLDER)` and `hil.open_trace(TRACE, dbc=DBC)` (hil.report.runfolder;
imported on first use, so `import hil` stays light).
"""

from hil import build

build.choose()     # the compiled modules, or pure Python: decided before any of them is imported

from hil.can import lazy_mf4  # noqa: E402

__all__ = ["open_run", "open_trace"]

lazy_mf4.install()        # python-can's MF4 support loads asammdf when first used, not on `import can`


def __getattr__(name: str):
    if name in __all__:
        # lazy: every module of railhil imports this package first: 9 ms, not 370 ms (-X importtime)
        from hil.report import runfolder

        return getattr(runfolder, name)
    raise AttributeError(f"module 'hil' has no attribute {name!r}")

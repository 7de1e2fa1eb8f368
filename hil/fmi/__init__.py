"""Models from other tools: an FMU (FMI 2.0 / 3.0 co-simulation, run by FMPy) as the plant or as a node, and
railhil's own plant and BECU exported as FMI 2.0 co-simulation FMUs (PythonFMU).  docs/fmu.md is the user's
page."""

"""`import railhil`: the Python face of railhil for notebooks and scripts.

    import railhil
    run = railhil.open_run("runs/default-lockstep-20261201-120000")
    trace = railhil.open_trace("trace.mf4", dbc="dbc/train_brake.dbc")

The same as `hil.open_run` / `hil.open_trace` (hil.report.runfolder); the package itself is `hil`.
"""

__all__ = ["open_run", "open_trace"]


def __getattr__(name: str):
    if name in __all__:
        import hil

        return getattr(hil, name)
    raise AttributeError(f"module 'railhil' has no attribute {name!r}")

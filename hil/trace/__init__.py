"""Traces: reading any python-can format, numpy columns, fast decoding and timing analysis.

- `readers`    open a trace of any python-can format (or candump text on stdin), one-line errors
- `columns`    a trace as numpy columns (BLF and candump in bulk)
- `fastdecode` block decoding for `railhil trace decode`
- `timing`     cycle-time conformance against the DBC, bus load, latency chains
"""

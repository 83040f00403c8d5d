"""Captures: the recorded test as files (CSV + JSON sidecar, COMTRADE, recorder exports).

`read_capture` / `write_capture` for the project's own format (`capture_sha256`: the hash a
result or diagnosis records of a capture file), `read_comtrade` for IEEE C37.111
records, `importer.import_export` for vendor exports; every refusal is a `CaptureError`.
"""
from bench_ctl.capture.capture import Capture, capture_sha256, read_capture, write_capture
from bench_ctl.capture.errors import CaptureError

__all__ = ["Capture", "CaptureError", "capture_sha256", "read_capture", "write_capture"]

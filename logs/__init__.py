"""Logs: MCAP message definitions, the writer, the checking reader and recovery of damaged logs."""

from deepslam._lazy import lazy_exports

_EXPORTS = {  # public name: the module that defines it
    "LogFrame": "frames",
    "LogWriter": "writer",
    "LogError": "reader",
    "LogWriteError": "writer",
    "read_frames": "reader",
    "read_metadata": "reader",
    "check_log": "reader",
    "recover": "recover",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

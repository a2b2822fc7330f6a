"""Flight records: one MCAP file per flight (see :mod:`recorder`), read back by :mod:`reader`."""

from quadnav_onboard.record.reader import FlightRecord, RecordError, read_record
from quadnav_onboard.record.recorder import FlightRecorder, NullRecorder, Recorder, RecorderError

__all__ = [
    "FlightRecord",
    "FlightRecorder",
    "NullRecorder",
    "RecordError",
    "Recorder",
    "RecorderError",
    "read_record",
]

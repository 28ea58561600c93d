"""Recording sessions: the :class:`Source` interface, the :class:`Recorder`, and the simulator (``sim``)."""

from phonepose.record.recorder import Recorder, RecordResult
from phonepose.record.source import Record, Source

__all__ = ["Record", "RecordResult", "Recorder", "Source"]

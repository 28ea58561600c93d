"""The interface between whatever produces a session (the simulator, live phones) and the recorder.

A :class:`Source` has two parts:
- :meth:`Source.static` -- messages that describe the session and do not change (session info,
  camera calibration, extrinsics, marker spec, ...). The recorder writes them first.
- iterating the source -- every other message as a :class:`Record`, in non-decreasing
  ``log_time_ns`` order (the recorder checks this per channel).

``duration_ns`` (if known) lets the recorder show progress; ``close()`` releases devices.
The recorder knows nothing else about where the data comes from.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, NamedTuple, Protocol, runtime_checkable


class Record(NamedTuple):
    topic: str
    message: Any             # a protobuf message of the topic's type (phonepose.schemas.topics)
    log_time_ns: int         # capture time on the display's clock (receipt time for controller streams)
    publish_time_ns: int     # arrival time at the recorder


@runtime_checkable
class Source(Protocol):
    start_ns: int                    # log time of the session start

    @property
    def duration_ns(self) -> int | None:
        """None for open-ended live sources (read-only here, so a source may declare it ``int``)."""
        ...

    def static(self) -> list[Record]:
        """Messages written once, before everything else."""
        ...

    def __iter__(self) -> Iterator[Record]:
        """The stream, in log-time order."""
        ...

    def close(self) -> None:
        ...

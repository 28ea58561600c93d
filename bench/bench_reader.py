"""Chunk parsing through the mcap library versus hand-written ``struct`` parsing, on a whole playback.

The session reader parses each chunk with ``mcap.stream_reader.breakup_chunk`` (the library made
for the job); the hand-written ``struct`` loop here is only the comparison. Both run side by side
in one process, alternated, best of ``ROUNDS``: a whole ``--tracker paper`` playback (what a user
waits for) and, for scale, one pass over every message.
The hand-written parser would be worth keeping only if the whole playback were > 10 % faster.

    python -m bench reader        or        python bench/bench_reader.py
"""

from __future__ import annotations

import struct
import tempfile
import time
import zlib
from pathlib import Path

ROUNDS = 5
_RECORD_HEAD = struct.Struct("<BQ")
_MESSAGE_HEAD = struct.Struct("<HIQQ")


def _struct_chunk_messages(self, ci, wanted, start_ns, end_ns):
    """The former hand-written parser (zstd only), with the library's Message records as output."""
    import zstandard
    from mcap.data_stream import ReadDataStream
    from mcap.records import Chunk, Message

    self._file.seek(ci.chunk_start_offset + 9)
    chunk = Chunk.read(ReadDataStream(self._file))
    data = zstandard.decompress(chunk.data, chunk.uncompressed_size) if chunk.compression == "zstd" else chunk.data
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise ValueError("chunk CRC mismatch")
    out, pos, n = [], 0, len(data)
    while pos < n:
        op, length = _RECORD_HEAD.unpack_from(data, pos)
        pos += 9
        end = pos + length
        if op == 0x05:
            cid, seq, log_time, publish_time = _MESSAGE_HEAD.unpack_from(data, pos)
            if ((wanted is None or cid in wanted) and (start_ns is None or log_time >= start_ns)
                    and (end_ns is None or log_time < end_ns)):
                out.append(Message(channel_id=cid, sequence=seq, log_time=log_time, publish_time=publish_time,
                                   data=data[pos + 22:end]))
        pos = end
    return out


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main() -> dict:
    from bench.bench_playback import _make_session
    from phonepose.playback.engine import run_playback
    from phonepose.session import SessionReader

    library = SessionReader._chunk_messages
    with tempfile.TemporaryDirectory() as tmp:
        session, what = _make_session(Path(tmp))

        def playback() -> None:
            run_playback(session, trackers=["paper"], write_outputs=False)

        def read_all() -> None:
            with SessionReader(session) as r:
                for _ in r.raw_messages():
                    pass

        times: dict[str, list[float]] = {"lib_play": [], "struct_play": [], "lib_read": [], "struct_read": []}
        for _ in range(ROUNDS):
            for name, parser in (("lib", library), ("struct", _struct_chunk_messages)):
                SessionReader._chunk_messages = parser
                try:
                    times[f"{name}_play"].append(_timed(playback))
                    times[f"{name}_read"].append(_timed(read_all))
                finally:
                    SessionReader._chunk_messages = library
    best = {k: min(v) for k, v in times.items()}
    out = {
        "session": what,
        "playback_library_s": round(best["lib_play"], 3), "playback_struct_s": round(best["struct_play"], 3),
        "playback_ratio": round(best["lib_play"] / best["struct_play"], 3),
        "read_library_s": round(best["lib_read"], 3), "read_struct_s": round(best["struct_read"], 3),
        "read_ratio": round(best["lib_read"] / best["struct_read"], 3),
    }
    print(f"whole playback --tracker paper ({what}), best of {ROUNDS}: mcap library {out['playback_library_s']} s, "
          f"struct {out['playback_struct_s']} s: {out['playback_ratio']}x")
    print(f"reading every message: library {out['read_library_s']} s, struct {out['read_struct_s']} s: "
          f"{out['read_ratio']}x")
    return out


if __name__ == "__main__":
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    main()

"""Recording throughput of the simulator, and what the MCAP writer costs.

Measured side by side in one run (best of ``ROUNDS``; the machine is shared and noisy):
- ``record``: ``record_sim`` of exp2 TRI2 trial 1 to a file: seconds of session per second of
  wall time (x real time; target >= 5x), and its parts: the simulation without rendering (world,
  plan, VIO, IMU, mocap), the per-frame render + JPEG cost, and the writer.
- ``writer``: the same records written with ``SessionWriter`` (zstd, 1 MiB chunks, 1 s
  flushes) vs the same serialized bytes appended to a plain file (the floor).

    python -m bench record          or          python bench/bench_record.py
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

ROUNDS = 3
TARGET_X_REAL_TIME = 5.0


def _best(fn, rounds=ROUNDS):
    best = float("inf")
    out = None
    for _ in range(rounds):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main() -> dict:
    import numpy as np

    from phonepose.record.sim import SimSession, SimSource, record_sim
    from phonepose.session import SessionWriter

    args = dict(scenario="exp2", path="TRI2", trial=1, seed=0)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        out = tmp / "s.mcap"
        t_record, result = _best(lambda: record_sim(out, force=True, **args))   # (the same file each round)
        session_s = result.duration_ns / 1e9
        # CPU time of one more run: on a shared machine wall time includes waiting for a core
        c0 = time.process_time()
        record_sim(out, force=True, **args)
        cpu_record = time.process_time() - c0
        t_build, session = _best(lambda: SimSession(args["scenario"], args["path"], args["trial"], args["seed"]))
        n_frames = len(session.t_cam)
        rng = np.random.default_rng(0)
        _ = session.renderer  # build the renderer (backgrounds, maps, noise bank) outside the timing

        def render_all():
            for i in range(n_frames):
                session.renderer.encode(session.render_frame(i, rng))

        t_render, _ = _best(render_all)
        records = list(SimSource(session).static()) + list(SimSource(session))
        payloads = [(r, r.message.SerializeToString()) for r in records]

        def write_mcap():
            with SessionWriter(tmp / "w.mcap") as w:
                for r, data in payloads:
                    w.write_bytes(r.topic, r.message, data, r.log_time_ns, r.publish_time_ns)

        def write_plain():
            with open(tmp / "w.bin", "wb") as f:
                for _, data in payloads:
                    f.write(data)
                f.flush()
                os.fsync(f.fileno())

        t_mcap, _ = _best(write_mcap)
        t_plain, _ = _best(write_plain)
        size = os.path.getsize(out)
        raw = sum(len(d) for _, d in payloads)
    res = {
        "session": "exp2 TRI2 trial 1 seed 0",
        "session_s": round(session_s, 2),
        "frames": n_frames,
        "record_wall_s": round(t_record, 3),
        "x_real_time": round(session_s / t_record, 2),
        "x_real_time_cpu": round(session_s / cpu_record, 2),
        "target_x_real_time": TARGET_X_REAL_TIME,
        "ms_per_frame_all_in": round(1e3 * t_record / n_frames, 2),
        "simulation_build_s": round(t_build, 3),
        "render_jpeg_ms_per_frame": round(1e3 * t_render / n_frames, 2),
        "writer_s": round(t_mcap, 3),
        "plain_file_s": round(t_plain, 3),
        "writer_vs_plain": round(t_mcap / t_plain, 2),
        "writer_MB_per_s": round(raw / 1e6 / t_mcap, 1),
        "file_MB": round(size / 1e6, 2),
        "messages": len(payloads),
    }
    print(f"record {res['session']}: {session_s:.1f} s of session in {t_record:.2f} s = "
          f"{res['x_real_time']:.1f}x real time (target >= {TARGET_X_REAL_TIME}x; {res['x_real_time_cpu']:.1f}x in CPU time), "
          f"{res['ms_per_frame_all_in']:.2f} ms per camera frame all-in")
    print(f"  parts: simulation build {t_build:.2f} s, render+JPEG {res['render_jpeg_ms_per_frame']:.2f} ms/frame, "
          f"writer {t_mcap:.2f} s")
    print(f"writer: {len(payloads)} messages, {raw / 1e6:.1f} MB: SessionWriter {t_mcap:.3f} s vs plain file "
          f"{t_plain:.3f} s = {res['writer_vs_plain']:.1f}x ({res['writer_MB_per_s']} MB/s)")
    return res


if __name__ == "__main__":
    main()

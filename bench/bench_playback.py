"""Playback of every tracker on a long session against the decode+detect floor, and of
the paper's seven trackers on a short one against the frames it decodes.

Part 1: an exp1 session (112 s, ~3360 frames, 2250 ticks at 20 Hz). The floor is what a
user starting from OpenCV would run: JPEG-decode every camera frame of the session and run a
plain ``ArucoDetector.detectMarkers`` (default parameters) on it. Playback ``--tracker all``
(T1-T7, T7L, T8; all outputs), and the same with ``--rerun FILE.rrd``, alternate with it in one
process, median of ``LONG_ROUNDS``. Playback can be under the floor: it decodes only the frames
a tick carries (20 of 30 Hz) and recognises the marker in a region of interest while it tracks.
Targets: <= 0.5x the floor, <= 0.7x with Rerun, wall and CPU. Playback recognises each frame a few ticks ahead
on a worker thread (``SharedStages.prefetch``), so with a second core free its wall time is about
its recognition's alone; the CPU time of the process (all threads) is reported beside, the work
done whatever the cores.

Part 2: playback throughput of the paper's seven trackers (``--tracker paper``, T1-T7)
without and with Rerun, next to the floor.

The floor is what no playback can avoid: JPEG decode + marker recognition of the same camera
frames the engine decodes (the frames the ticks carry as new). Playback adds the file pass, the
tick scheduling, the seven trackers T1-T7 (the target's set; ``all`` also runs our T8), the output
files and (optionally) Rerun logging. Reported as frames/s and as ratios to the floor, measured side
by side in one run (best of ``ROUNDS``), by wall clock and by the process's CPU time (all threads, so
Rerun's writer thread counts).
Targets: <= 1.3x the floor without Rerun, <= 1.6x with.

Session: a simulator session (``phonepose record sim --scenario exp2 ...``) when the simulator
is available, else the hand-made playback test session at 640x480 (said so in the output).

    python -m bench playback         or         python bench/bench_playback.py
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROUNDS = 5
TARGET_NO_RERUN = 1.3
TARGET_RERUN = 1.6
LONG_ROUNDS = 3
TARGET_LONG = 0.5
TARGET_LONG_RERUN = 0.7


def _make_session(tmp: Path) -> tuple[Path, str]:
    out = tmp / "sim.mcap"
    try:
        r = subprocess.run([sys.executable, "-m", "phonepose", "record", "sim", "--scenario", "exp2", "--path", "TRI2",
                            "--trial", "1", "--seed", "0", "--out", str(out)], capture_output=True, text=True,
                           timeout=900)
        if r.returncode == 0 and out.exists():
            return out, "simulator exp2 TRI2 trial 1 seed 0"
        lines = [ln.strip(" │╭╮╰╯─") for ln in r.stderr.splitlines()]
        lines = [ln for ln in lines if ln]
        why = f"exit {r.returncode}: {lines[-1] if lines else ''}"
    except (OSError, subprocess.TimeoutExpired) as exc:
        why = str(exc)
    print(f"simulator not available ({why}); using the hand-made playback test session (640x480, 20 s)")
    from phonepose.testing.playback_session import write_test_session

    hand = tmp / "hand.mcap"
    write_test_session(hand, duration_s=20.0, width=640, height=480, in_view_fraction=0.5)
    return hand, "hand-made test session 640x480 20 s (simulator not available)"


def _new_frames(session: Path) -> list:
    """The camera frames the ticks carry as new (what the shared stages decode), with their tick."""
    from phonepose.playback.scheduler import TickScheduler
    from phonepose.session import SessionReader
    from phonepose.session.context import read_context

    frames = []
    with SessionReader(session) as r:
        ctx = read_context(r)
        for tick in TickScheduler(r, ctx):
            if tick.new_frame is not None:
                frames.append((tick.frame, tick.frame.t_ns, tick.T_dvio_display))
    return frames, ctx


def _floor(frames, ctx) -> tuple[float, float]:
    from phonepose.pipeline.markers import MarkerRecognizer
    from phonepose.pipeline.shared import decode_gray

    rec = MarkerRecognizer(ctx.camera, ctx.marker)
    t0, c0 = time.perf_counter(), time.process_time()
    for image, t_ns, T in frames:
        gray = decode_gray(image.data).gray
        rec.recognize(gray, T, t_ns)
    return time.perf_counter() - t0, time.process_time() - c0


def _playback(session: Path, out: Path, rrd: Path | None, trackers: str = "paper") -> tuple[float, float, object]:
    from phonepose.playback.engine import run_playback

    t0, c0 = time.perf_counter(), time.process_time()
    res = run_playback(session, trackers=trackers, out_dir=out, rerun_path=rrd)
    return time.perf_counter() - t0, time.process_time() - c0, res


def _warm_up(tmp: Path) -> None:
    """Untimed: one playback with Rerun of a 2 s hand-made session, so that no timed round pays the
    modules imported on first use (Rerun's SDK, the metrics). The floor's imports (cv2) are outside
    its timing too, so no timed round pays their compiling where no bytecode is cached
    (PYTHONDONTWRITEBYTECODE=1)."""
    from phonepose.playback.engine import run_playback
    from phonepose.testing.playback_session import write_test_session

    session = tmp / "warm-up.mcap"
    write_test_session(session, duration_s=2.0)
    run_playback(session, trackers="all", out_dir=tmp / "warm-up", rerun_path=tmp / "warm-up.rrd")


def _all_frames(session: Path) -> list[bytes]:
    """Every camera frame's JPEG bytes (read before timing: the floor is decode + detect only)."""
    from phonepose.schemas.topics import Topic
    from phonepose.session import SessionReader

    with SessionReader(session) as r:
        return [m.msg.data for m in r.messages([Topic.CAMERA_IMAGE])]


def _plain_floor(jpegs: list[bytes], dictionary: str) -> tuple[float, float]:
    """(wall, CPU) seconds of decode + plain detectMarkers of every frame."""
    import cv2
    import numpy as np

    from phonepose.pipeline.markers import aruco_dictionary

    detector = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), cv2.aruco.DetectorParameters())
    t0, c0 = time.perf_counter(), time.process_time()
    for data in jpegs:
        detector.detectMarkers(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE))
    return time.perf_counter() - t0, time.process_time() - c0


def long_session(tmp: Path, session: Path | None = None) -> dict:
    """Part 1: ``--tracker all`` on exp1 against decode + plain detectMarkers of every frame
    (``session``: an exp1 session recorded before, else one is recorded into ``tmp``)."""
    import statistics

    from phonepose.session import SessionReader
    from phonepose.session.context import read_context

    if session is None:
        session = tmp / "exp1.mcap"
        subprocess.run([sys.executable, "-m", "phonepose", "record", "sim", "--scenario", "exp1", "--seed", "0",
                        "--out", str(session), "-q"], check=True, capture_output=True, timeout=1800)
    jpegs = _all_frames(session)
    with SessionReader(session) as r:
        dictionary = read_context(r).marker.dictionary
    _warm_up(tmp)
    floor, plain, rerun = [], [], []
    cpu: dict[str, list[float]] = {"floor": [], "plain": [], "rerun": []}   # process CPU time, all threads
    ticks = 0
    for k in range(LONG_ROUNDS):
        w, c = _plain_floor(jpegs, dictionary)
        floor.append(w)
        cpu["floor"].append(c)
        w, c, res = _playback(session, tmp / f"long{k}", None, trackers="all")
        plain.append(w)
        cpu["plain"].append(c)
        ticks = res.n_ticks
        w, c, _ = _playback(session, tmp / f"longr{k}", tmp / f"longr{k}.rrd", trackers="all")
        rerun.append(w)
        cpu["rerun"].append(c)
    f, p, r = (statistics.median(x) for x in (floor, plain, rerun))
    cf, cp, cr = (statistics.median(cpu[k]) for k in ("floor", "plain", "rerun"))
    out = {"long_session": "simulator exp1 seed 0", "long_frames": len(jpegs), "long_ticks": ticks,
           "long_floor_s": f, "long_playback_all_s": p, "long_playback_all_rerun_s": r,
           "long_ratio_all": p / f, "long_ratio_all_rerun": r / f,
           "long_cpu_ratio_all": cp / cf, "long_cpu_ratio_all_rerun": cr / cf,
           "long_rounds": {"floor_s": floor, "playback_s": plain, "rerun_s": rerun,
                           "cpu_floor_s": cpu["floor"], "cpu_playback_s": cpu["plain"], "cpu_rerun_s": cpu["rerun"]}}
    print(f"part 1: exp1 session, {len(jpegs)} frames, {ticks} ticks (median of {LONG_ROUNDS}, alternating)")
    print(f"  floor: decode + plain detectMarkers of every frame  {f:6.2f} s   1.00x")
    print(f"  playback --tracker all                              {p:6.2f} s   {p / f:.2f}x  (target <= {TARGET_LONG}x)")
    print(f"  playback --tracker all --rerun                      {r:6.2f} s   {r / f:.2f}x  "
          f"(target <= {TARGET_LONG_RERUN}x)")
    print(f"  CPU time (all threads: the work done, whatever the cores): playback {cp / cf:.2f}x the floor's, "
          f"with --rerun {cr / cf:.2f}x")
    for k in range(LONG_ROUNDS):
        print(f"    round {k + 1}: floor {floor[k]:.2f} s, playback {plain[k]:.2f} s ({plain[k] / floor[k]:.2f}x), "
              f"--rerun {rerun[k]:.2f} s ({rerun[k] / floor[k]:.2f}x)")
    return out


def main() -> dict:
    with tempfile.TemporaryDirectory(prefix="bench-playback-long-") as d:
        long = long_session(Path(d))
    return {**long, **short_session()}


def short_session() -> dict:
    """Part 2: ``--tracker paper`` on exp2 TRI2 against decode + recognition of the frames it decodes."""
    with tempfile.TemporaryDirectory(prefix="bench-playback-") as d:
        tmp = Path(d)
        session, source = _make_session(tmp)
        frames, ctx = _new_frames(session)
        n = len(frames)
        if n == 0:
            print("the session has no camera frames: nothing to measure")
            return {"skipped": "no camera frames", "session": source}
        inf = float("inf")
        best = {"floor": inf, "no_rerun": inf, "rerun": inf}          # wall clock
        cpu = {"floor": inf, "no_rerun": inf, "rerun": inf}           # CPU of the process (all threads)
        ticks = 0
        for k in range(ROUNDS):
            w, c = _floor(frames, ctx)
            best["floor"], cpu["floor"] = min(best["floor"], w), min(cpu["floor"], c)
            w, c, res = _playback(session, tmp / f"o{k}", None)
            best["no_rerun"], cpu["no_rerun"] = min(best["no_rerun"], w), min(cpu["no_rerun"], c)
            ticks = res.n_ticks
            w, c, _ = _playback(session, tmp / f"r{k}", tmp / f"r{k}.rrd")
            best["rerun"], cpu["rerun"] = min(best["rerun"], w), min(cpu["rerun"], c)
        rrd_mb = (tmp / f"r{ROUNDS - 1}.rrd").stat().st_size / 1e6
    result = {
        "session": source,
        "frames": n,
        "ticks": ticks,
        "floor_fps": n / best["floor"],
        "playback_all_fps": n / best["no_rerun"],
        "playback_all_rerun_fps": n / best["rerun"],
        "ratio_no_rerun": best["no_rerun"] / best["floor"],
        "ratio_rerun": best["rerun"] / best["floor"],
        "cpu_ratio_no_rerun": cpu["no_rerun"] / cpu["floor"],
        "cpu_ratio_rerun": cpu["rerun"] / cpu["floor"],
        "target_no_rerun": TARGET_NO_RERUN,
        "target_rerun": TARGET_RERUN,
        "rrd_mb": rrd_mb,
    }
    print(f"part 2: session: {source}; {n} decoded frames over {ticks} ticks (best of {ROUNDS})")
    print(f"  floor (decode + detect)         {result['floor_fps']:8.1f} frames/s   1.00x")
    print(f"  playback --tracker paper        {result['playback_all_fps']:8.1f} frames/s   "
          f"{result['ratio_no_rerun']:.2f}x  (target <= {TARGET_NO_RERUN}x)")
    print(f"  playback --tracker paper --rerun{result['playback_all_rerun_fps']:8.1f} frames/s   "
          f"{result['ratio_rerun']:.2f}x  (target <= {TARGET_RERUN}x; .rrd {rrd_mb:.1f} MB)")
    print(f"  CPU-time ratios (all threads; steadier on a shared machine): {result['cpu_ratio_no_rerun']:.2f}x "
          f"without Rerun, {result['cpu_ratio_rerun']:.2f}x with")
    return result


if __name__ == "__main__":
    main()

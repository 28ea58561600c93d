"""Run every benchmark side by side: ``python -m bench [name ...]``.

Each ``bench/bench_<name>.py`` has ``main() -> dict`` that measures our code next to its
floor or the tool a user would pick instead, in the same run, and prints ratios (machines
are shared and noisy: compare within a run, never across runs). At the end, one table of
every figure against its target; everything goes to bench/results.json, and the figures of a
recent run to docs/performance.md.
"""

from __future__ import annotations

import importlib
import json
import os
import pathlib
import platform
import sys
import time
import timeit

import cv2


def machine() -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    out = {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform()}
    for mod, attr in (("numpy", "__version__"), ("cv2", "__version__"), ("scipy", "__version__"), ("mcap", "__version__")):
        try:
            out[mod] = getattr(importlib.import_module(mod), attr)
        except Exception:  # noqa: BLE001 - a missing module is just not reported
            pass
    try:
        out["load_average"] = [round(v, 2) for v in os.getloadavg()]
    except OSError:
        pass
    # the interpreter's own speed, to read per-tick figures across machines: VMs differ ~3x here while
    # OpenCV's floor barely moves (docs/performance.md#reading-the-figures)
    out["python_sum_range_1000_us"] = round(min(timeit.repeat("sum(range(1000))", number=2000, repeat=5)) / 2000 * 1e6, 2)
    return out


# (bench, key, what, target text, met(value) -> bool) for the summary table
SUMMARY = [
    ("playback", "long_ratio_all", "playback --tracker all vs decode+plain detect, exp1 (median 3)", "<= 0.5x",
     lambda v: v <= 0.5),
    ("playback", "long_ratio_all_rerun", "  same with --rerun", "<= 0.7x", lambda v: v <= 0.7),
    ("playback", "long_cpu_ratio_all", "  same, CPU time of all threads (no --rerun)", "<= 0.5x", lambda v: v <= 0.5),
    ("playback", "long_cpu_ratio_all_rerun", "  same, CPU time with --rerun", "<= 0.7x", lambda v: v <= 0.7),
    ("playback", "ratio_no_rerun", "playback --tracker paper vs decode+detect floor (wall)", "<= 1.3x", lambda v: v <= 1.3),
    ("playback", "cpu_ratio_no_rerun", "  same, CPU time", "<= 1.3x", lambda v: v <= 1.3),
    ("playback", "ratio_rerun", "playback --tracker paper --rerun vs floor (wall)", "<= 1.6x", lambda v: v <= 1.6),
    ("playback", "cpu_ratio_rerun", "  same, CPU time", "<= 1.6x", lambda v: v <= 1.6),
    ("pipeline", "ratio_ours_sequence_vs_plain", "our recognition vs plain detectMarkers (sequence)", "cost of accuracy", None),
    ("pipeline", "ratio_ours_cold_vs_plain", "our recognition vs plain detectMarkers (cold)", "cost of accuracy", None),
    ("decode", "decoded_vs_camera_frames", "exp1 frames playback decodes / camera frames", "report", None),
    ("decode", "reduced2_vs_full_decode", "JPEG decode at half size / full size (OpenCV's DCT scaling)", "report",
     None),
    ("decode", "half_vs_full_contour", "full-frame marker search at half size / full size", "report", None),
    ("evaluation", "tum_speedup", "evo APE+RPE time / ours, TUM (with association)", ">= 10x", lambda v: v >= 10),
    ("evaluation", "euroc_speedup", "  same, EuRoC (with association)", ">= 10x", lambda v: v >= 10),
    ("evaluation", "kitti_speedup", "  same, KITTI (index-matched)", ">= 10x", lambda v: v >= 10),
    ("evaluation", "speedup_metrics", "evo APE+RPE time / ours (same numbers)", ">= 10x", lambda v: v >= 10),
    ("evaluation", "speedup_incl_loading", "  same, including loading the files", ">= 10x", lambda v: v >= 10),
    ("record", "x_real_time", "record sim, x real time (wall)", ">= 5x", lambda v: v >= 5),
    ("record", "writer_vs_plain", "SessionWriter vs plain file, same bytes", "floor 1x", None),
    ("ticks", "T1_T7_cpu_ms_per_tick", "T1-T7 together per tick, ms CPU", "<= 0.1 ms", lambda v: v <= 0.1),
    ("ticks", "T1_T7_ms_per_tick", "  same, wall", "report", None),
    ("ticks", "shared_own_cpu_ms_per_tick", "shared stages' non-OpenCV work per tick, ms CPU", "<= 0.3 ms",
     lambda v: v <= 0.3),
    ("ticks", "shared_own_ms_per_tick", "  same, wall", "report", None),
    ("ticks", "T8_cpu_ms_per_tick", "T8 per tick, ms CPU", "<= 0.2 ms", lambda v: v <= 0.2),
    ("ticks", "T8_ms_per_tick", "  same, wall", "report", None),
    ("fusion", "T8_ms_per_tick", "T8 (fused tracker) per tick, ms", "< 2 ms", lambda v: v < 2.0),
    ("fusion", "t8_vs_shared_stages", "  same / shared stages (decode+detect+anchor)", "report", None),
    ("fusion", "t8_accel_share", "  T8's accelerometer prediction, share of T8", "report", None),
    ("fusion", "accel_fit_third_vs_full", "  accelerometer fit on a third of its window / whole window", "report",
     None),
    ("memory", "peak_ratio_long_vs_short", "peak RSS, 10-min / 1-min session playback", "<= 1.05x",
     lambda v: v <= 1.05),
    ("memory", "ticks_peak_ratio_long_vs_short", "  same, up to the last tick (before the metrics)", "<= 1.1x",
     lambda v: v <= 1.1),
    ("batch", "speedup_2_vs_1", "batch, 2 local workers vs 1 (wall, same rows)", "report (~1.6-1.9x)", None),
    ("batch", "dask_overhead_vs_local_2", "  same batch on a Dask LocalCluster (2) vs local 2", "report", None),
    ("batch", "table_rewrite_vs_rows_hash", "batch table rewrite (200k rows), columns vs rows-JSON checksum", "report",
     None),
]


def print_summary(results: dict) -> None:
    print("\n=== summary (ratios measured side by side in this run) ===")
    for bench, key, what, target, met in SUMMARY:
        value = results.get(bench, {}).get(key) if isinstance(results.get(bench), dict) else None
        if value is None:
            continue
        verdict = "" if met is None else ("met" if met(value) else "MISSED")
        print(f"  {what:<62} {value:8.3f}  {target:<17} {verdict}")


def main(argv: list[str]) -> int:
    here = pathlib.Path(__file__).parent
    known = sorted(p.stem.removeprefix("bench_") for p in here.glob("bench_*.py"))
    if any(a in ("-h", "--help") for a in argv):
        print(f"usage: python -m bench [NAME ...]   (NAME: {', '.join(known)}; none: all, written to results.json)")
        return 0
    unknown = [a for a in argv if a not in known]
    if unknown:
        print(f"error: no benchmark named {unknown[0]!r} (known: {', '.join(known)})", file=sys.stderr)
        return 2
    names = argv or known
    results = {"machine": machine(), "command": "python -m bench " + " ".join(argv)}
    t0 = time.perf_counter()
    failed = []
    # fusion, pipeline and ticks time OpenCV on one thread (cv2.setNumThreads(1)); the next item must start
    # from OpenCV's default again: the playback item's floor (plain detectMarkers) spreads over the cores
    opencv_threads = cv2.getNumThreads()
    for name in names:
        print(f"\n=== {name} ===", flush=True)
        mod = importlib.import_module(f"bench.bench_{name}")
        try:
            results[name] = mod.main()
        except Exception as exc:  # noqa: BLE001 - one broken item must not lose the others' figures
            print(f"error: bench {name} failed: {type(exc).__name__}: {exc}", file=sys.stderr)
            results[name] = {"error": f"{type(exc).__name__}: {exc}"}
            failed.append(name)
        finally:
            cv2.setNumThreads(opencv_threads)
    results["total_s"] = round(time.perf_counter() - t0, 1)
    print_summary(results)
    m = results["machine"]
    print(f"\nmachine: {m['cpu']}, {m['cores']} cores, Python {m['python']}, numpy {m.get('numpy')}, "
          f"OpenCV {m.get('cv2')}; Python speed: sum(range(1000)) {m.get('python_sum_range_1000_us')} us; "
          f"load average at start {m.get('load_average')}; total {results['total_s']} s")
    # a full run is the record; a partial one (or one with a failed item) must not overwrite it
    out = here / ("results.json" if not argv and not failed else "results_partial.json")
    out.write_text(json.dumps(results, indent=2))
    print(f"wrote {out}")
    if failed:
        print(f"error: {len(failed)} item(s) failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

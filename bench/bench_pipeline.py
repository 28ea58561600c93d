"""Tracking pipeline cost per 640x480 frame, side by side in one run.

- ``ours``: MarkerRecognizer (CONTOUR full frame -> APRILTAG on a crop, bias fixes, IPPE_SQUARE
  + continuity + LM), on independent frames (cold: every frame goes through the full-frame
  pass) and on a smooth sequence (warm: the crop around last frame's position is tried first).
- ``plain``: ``ArucoDetector.detectMarkers`` with default parameters on the same frames
  (detection only: the floor a user would start from), and the same + IPPE_SQUARE for accuracy.
- ``apriltag_full``: APRILTAG refinement on the full frame (what the crop avoids).
- ``shared + 7 trackers``: SharedStages.process (JPEG decode + recognition + anchor mapping)
  plus all seven trackers stepping, per tick.

Frames are rendered with phonepose.testing.marker_images (5 cm DICT_4X4_50 marker, fx = 500,
blur + noise + JPEG q85). OpenCV is pinned to one thread so the figures do not depend on what
the other core is doing.
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from phonepose.geometry import Pose
from phonepose.pipeline.markers import MarkerRecognizer, aruco_dictionary, marker_object_points
from phonepose.pipeline.shared import SharedStages
from phonepose.pipeline.trackers import make_trackers
from phonepose.pipeline.types import Frame, MarkerModel, SessionContext, Tick
from phonepose.testing.marker_images import encode_jpeg, looking_at, pinhole_camera, render_marker

CAMERA = pinhole_camera()
MARKER = MarkerModel("DICT_4X4_50", 7, 0.05, Pose.identity())


def _frames(poses: list[Pose], rng: np.random.Generator) -> list[tuple[np.ndarray, bytes]]:
    out = []
    for pose in poses:
        gray = render_marker(CAMERA, MARKER, pose, blur_sigma=rng.uniform(0.4, 0.9), noise_sigma=rng.uniform(1.5, 3.0),
                             rng=rng)
        data = encode_jpeg(gray, 85)
        out.append((cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE), data))
    return out


def _random_poses(n: int, rng: np.random.Generator) -> list[Pose]:
    return [looking_at(rng.uniform(0.2, 0.6), rng.uniform(0, 60), rng.uniform(0, 360), rng.uniform(0, 360),
                       (rng.uniform(-0.06, 0.06), rng.uniform(-0.04, 0.04))) for _ in range(n)]


def _sequence_poses(n: int) -> list[Pose]:
    t = np.arange(n) / 20.0  # 20 Hz ticks
    return [looking_at(0.4 + 0.15 * np.sin(0.7 * s), 25 + 15 * np.sin(1.3 * s), 40 * s, 10 * s,
                       (0.05 * np.sin(0.9 * s), 0.03 * np.cos(1.1 * s))) for s in t]


def _ms(fn, items, repeat: int = 1) -> np.ndarray:
    times = []
    for _ in range(repeat):
        for item in items:
            t0 = time.perf_counter()
            fn(item)
            times.append(1000 * (time.perf_counter() - t0))
    return np.array(times)


def _stats(ms: np.ndarray) -> dict:
    return {"median_ms": round(float(np.median(ms)), 3), "p90_ms": round(float(np.percentile(ms, 90)), 3)}


def main() -> dict:
    cv2.setNumThreads(1)
    rng = np.random.default_rng(2024)
    random_poses = _random_poses(40, rng)
    random_frames = _frames(random_poses, rng)
    sequence_poses = _sequence_poses(120)
    sequence_frames = _frames(sequence_poses, rng)
    grays = [g for g, _ in random_frames]

    plain = cv2.aruco.ArucoDetector(aruco_dictionary(MARKER.dictionary), cv2.aruco.DetectorParameters())
    april_params = cv2.aruco.DetectorParameters()
    april_params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_APRILTAG
    april_full = cv2.aruco.ArucoDetector(aruco_dictionary(MARKER.dictionary), april_params)
    recognizer = MarkerRecognizer(CAMERA, MARKER)

    def ours_cold(gray):
        recognizer.reset()
        return recognizer.recognize(gray)

    for g in grays[:5]:  # warm-up
        plain.detectMarkers(g)
        ours_cold(g)

    results: dict = {}
    results["plain_detectMarkers"] = _stats(_ms(plain.detectMarkers, grays, repeat=3))
    results["ours_cold"] = _stats(_ms(ours_cold, grays, repeat=3))
    recognizer.reset()
    recognizer.stats.clear()
    seq_ms = []
    for _ in range(3):
        recognizer.reset()
        seq_ms.append(_ms(lambda g: recognizer.recognize(g, t_ns=None), [g for g, _ in sequence_frames]))
    results["ours_sequence"] = _stats(np.concatenate(seq_ms))
    results["ours_sequence"]["stages"] = dict(recognizer.stats)
    results["apriltag_full_frame"] = _stats(_ms(april_full.detectMarkers, grays[:15]))
    plain_ms = results["plain_detectMarkers"]["median_ms"]
    results["ratio_ours_cold_vs_plain"] = round(results["ours_cold"]["median_ms"] / plain_ms, 2)
    results["ratio_ours_sequence_vs_plain"] = round(results["ours_sequence"]["median_ms"] / plain_ms, 2)

    # accuracy on the same random frames: ours vs plain detectMarkers + IPPE_SQUARE (best solution)
    obj = marker_object_points(MARKER.size_m)
    errs = {"ours": ([], []), "plain+IPPE": ([], [])}
    for gray, pose in zip(grays, random_poses, strict=True):
        recognizer.reset()
        o = recognizer.recognize(gray)
        if o is not None:
            errs["ours"][0].append(1000 * o.T_camera_marker.distance_to(pose))
            errs["ours"][1].append(np.degrees(o.T_camera_marker.angle_to(pose)))
        corners, ids, _ = plain.detectMarkers(gray)
        if ids is not None and MARKER.id in ids:
            c = corners[list(ids.reshape(-1)).index(MARKER.id)].reshape(4, 1, 2).astype(np.float64)
            _, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, c, CAMERA.K, CAMERA.D, flags=cv2.SOLVEPNP_IPPE_SQUARE)
            p = Pose.from_cv(rvecs[0], tvecs[0])
            errs["plain+IPPE"][0].append(1000 * p.distance_to(pose))
            errs["plain+IPPE"][1].append(np.degrees(p.angle_to(pose)))
    results["accuracy"] = {
        k: {"detected": f"{len(v[0])}/{len(grays)}",
            "position_mm_median_p90": [round(float(np.median(v[0])), 2), round(float(np.percentile(v[0], 90)), 2)],
            "rotation_deg_median_p90": [round(float(np.median(v[1])), 2), round(float(np.percentile(v[1], 90)), 2)]}
        for k, v in errs.items()}

    # per tick: shared stages (JPEG decode + recognition + anchors) and the seven trackers on top
    context = SessionContext(camera=CAMERA, marker=MARKER)
    anchors = dict(T_dvio_anchor=Pose.from_rotvec([0, 0, 0.5], [1.0, 0.0, 0.0]),
                   T_cvio_anchor=Pose.from_rotvec([0, 0, -0.3], [0.0, 2.0, 0.0]))
    ticks = [Tick(index=i, t_ns=i * 50_000_000,
                  frame=Frame(data, "jpeg", i * 50_000_000, is_new=True, T_dvio_display=Pose.identity()),
                  T_dvio_display=Pose.identity(),
                  T_cvio_controller=Pose.from_rotvec([0, 0.01 * i, 0], [0.01 * i, 0, 0]), **anchors)
             for i, (_, data) in enumerate(sequence_frames)]
    stages = SharedStages(context)
    trackers = make_trackers("all")
    shared_ms, trackers_ms = [], []
    for _ in range(3):
        stages.reset()
        for t in trackers:
            t.reset()
        for tick in ticks:
            t0 = time.perf_counter()
            obs = stages.process(tick)
            t1 = time.perf_counter()
            for t in trackers:
                t.step(obs)
            t2 = time.perf_counter()
            shared_ms.append(1000 * (t1 - t0))
            trackers_ms.append(1000 * (t2 - t1))
    results["per_tick_shared_stages"] = _stats(np.array(shared_ms))
    results["per_tick_seven_trackers"] = _stats(np.array(trackers_ms))
    results["per_tick_total"] = _stats(np.array(shared_ms) + np.array(trackers_ms))

    width = max(len(k) for k in results)
    for key, value in results.items():
        print(f"{key:<{width}}  {value}")
    return results


if __name__ == "__main__":
    main()

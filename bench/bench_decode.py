"""What decoding less would save, side by side in one run: the choices behind playback's decode and its
full-frame marker search (docs/performance.md#decoding-and-the-full-frame-search).

On an exp1 session (seed 0), recorded once:

- the frames a playback decodes (those a tick carries first, ``Frame.is_new``) against the camera frames;
- per decoded frame, CPU time of OpenCV's full grayscale decode (what playback runs) against
  ``cv2.IMREAD_REDUCED_GRAYSCALE_2`` (libjpeg's DCT scaling to half size) and, when the ``simplejpeg`` package
  is installed, its full and half-size decodes, with whether its pixels equal OpenCV's;
- the full-frame CONTOUR search (the recogniser's coarse pass) on the full frame against the half-size one,
  timed and with how many frames each finds the marker in;
- the same search on the real photos of tests/data/opencv_contrib (markers of 17-34 px a side): markers found
  at full and at half size.

OpenCV runs on one thread; every time is the best of 3 passes of this thread's CPU time.
"""

from __future__ import annotations

import pathlib
import tempfile
import time
from collections.abc import Callable

import cv2
import numpy as np

_PHOTOS = pathlib.Path(__file__).resolve().parent.parent / "tests" / "data" / "opencv_contrib" / "images"
_FULL = cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION
_HALF = cv2.IMREAD_REDUCED_GRAYSCALE_2 | cv2.IMREAD_IGNORE_ORIENTATION


def _cpu_ms(fn: Callable, items: list, repeat: int = 3) -> float:
    best = float("inf")
    for _ in range(repeat):
        c0 = time.thread_time()
        for item in items:
            fn(item)
        best = min(best, (time.thread_time() - c0) / len(items))
    return best * 1e3


def _session_frames(session: pathlib.Path) -> tuple[list[bytes], int, int, object]:
    """(the frames the ticks decode, the camera frames, the ticks, the session context)."""
    from phonepose.playback.scheduler import TickScheduler
    from phonepose.session import SessionReader
    from phonepose.session.context import read_context
    from phonepose.topics import Topic

    with SessionReader(session) as reader:
        context = read_context(reader)
        ticks, decoded = 0, []
        for tick in TickScheduler(reader, context):
            ticks += 1
            if tick.frame is not None and tick.frame.is_new:
                decoded.append(tick.frame.data)
        camera = len(reader.log_times().get(Topic.CAMERA_IMAGE, ()))
    return decoded, camera, ticks, context


def _found(detector, image: np.ndarray, marker_id: int | None) -> int:
    _corners, ids, _ = detector.detectMarkers(image)
    if ids is None:
        return 0
    return int(marker_id in ids.reshape(-1)) if marker_id is not None else len(ids)


def _charuco_corners() -> dict:
    """Our corners on the 68 ChArUco markers of the real photos against the corners projected from the board's pose
    (tests/test_markers_real.py), and how many of those markers the coarse search finds at half size."""
    import json

    from phonepose.geometry import Pose
    from phonepose.pipeline.markers import MarkerRecognizer
    from phonepose.pipeline.types import CameraModel, MarkerModel

    ref = json.loads((_PHOTOS.parent / "ground_truth" / "charuco_reference_poses.json").read_text())
    camera = CameraModel(np.array(ref["camera_matrix"]), np.array(ref["dist_coeffs"]), 640, 480, Pose.identity())
    errors, found_half = [], 0
    for key, info in ref["images"].items():
        data = np.fromfile(_PHOTOS / pathlib.Path(key).name, np.uint8)
        full, half = cv2.imdecode(data, _FULL), cv2.imdecode(data, _HALF)
        for marker_id, corners in info["marker_corners_px"].items():
            recognizer = MarkerRecognizer(camera, MarkerModel("DICT_6X6_250", int(marker_id), 0.02, Pose.identity()))
            seen = recognizer.recognize(full)
            if seen is not None:
                errors += np.linalg.norm(seen.corners_px - np.array(corners), axis=1).tolist()
            found_half += _found(recognizer._fast, half, int(marker_id))
    return {"charuco_found": len(errors) // 4, "charuco_median_px": float(np.median(errors)),
            "charuco_p90_px": float(np.percentile(errors, 90)), "charuco_found_half": found_half}


def main() -> dict:
    from phonepose.pipeline.markers import MarkerRecognizer
    from phonepose.record.sim import record_sim

    cv2.setNumThreads(1)
    with tempfile.TemporaryDirectory() as tmp:
        session = pathlib.Path(tmp) / "exp1.mcap"
        record_sim(session, scenario="exp1", seed=0)
        decoded, camera, ticks, context = _session_frames(session)
    out: dict = {"camera_frames": camera, "ticks": ticks, "decoded_frames": len(decoded),
                 "decoded_vs_camera_frames": len(decoded) / camera}
    frames = decoded[::3]                     # a third of them, spread over the session
    buffers = [np.frombuffer(d, np.uint8) for d in frames]
    full_ms = _cpu_ms(lambda b: cv2.imdecode(b, _FULL), buffers)
    half_ms = _cpu_ms(lambda b: cv2.imdecode(b, _HALF), buffers)
    out.update(frames_timed=len(frames), decode_full_ms=full_ms, decode_reduced2_ms=half_ms,
               reduced2_vs_full_decode=half_ms / full_ms)
    line = (f"decode: {len(decoded)} of {camera} camera frames decoded over {ticks} ticks "
            f"({out['decoded_vs_camera_frames']:.2f}); per frame, ms CPU: OpenCV full {full_ms:.3f}, "
            f"IMREAD_REDUCED_GRAYSCALE_2 {half_ms:.3f} ({half_ms / full_ms:.2f}x)")
    try:
        import simplejpeg  # optional: libjpeg-turbo's own DCT scaling, not a dependency of phonepose
    except ImportError:
        line += "; simplejpeg not installed"
    else:
        w, h = context.camera.width, context.camera.height
        sj_ms = _cpu_ms(lambda d: simplejpeg.decode_jpeg(d, colorspace="GRAY"), frames)
        sj_half_ms = _cpu_ms(lambda d: simplejpeg.decode_jpeg(d, colorspace="GRAY", min_width=w // 2,
                                                              min_height=h // 2), frames)
        same = sum(np.array_equal(simplejpeg.decode_jpeg(d, colorspace="GRAY")[:, :, 0], cv2.imdecode(b, _FULL))
                   for d, b in zip(frames, buffers, strict=True))
        out.update(simplejpeg_full_ms=sj_ms, simplejpeg_half_ms=sj_half_ms, simplejpeg_half_vs_full_decode=sj_half_ms
                   / full_ms, simplejpeg_same_pixels=same)
        line += (f"; simplejpeg full {sj_ms:.3f}, half {sj_half_ms:.3f} ({sj_half_ms / full_ms:.2f}x), "
                 f"the same pixels as OpenCV in {same} of {len(frames)}")
    print(line)

    # the recogniser's coarse pass (CONTOUR refinement, the expected id only) at full and at half size
    fast = MarkerRecognizer(context.camera, context.marker)._fast
    marker_id = context.marker.id
    fulls = [cv2.imdecode(b, _FULL) for b in buffers]
    halves = [cv2.imdecode(b, _HALF) for b in buffers]
    c_full = _cpu_ms(lambda g: fast.detectMarkers(g), fulls)
    c_half = _cpu_ms(lambda g: fast.detectMarkers(g), halves)
    found_full = sum(_found(fast, g, marker_id) for g in fulls)
    found_half = sum(_found(fast, g, marker_id) for g in halves)
    out.update(contour_full_ms=c_full, contour_half_ms=c_half, half_vs_full_contour=c_half / c_full,
               contour_found_full=found_full, contour_found_half=found_half)
    # the real photos: every marker of their dictionary, full and half size
    photo_full = photo_half = 0
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_CONTOUR
    photo_detector = cv2.aruco.ArucoDetector(dictionary, params)
    for path in sorted(_PHOTOS.glob("*.jpg")):
        data = np.fromfile(path, np.uint8)
        photo_full += _found(photo_detector, cv2.imdecode(data, _FULL), None)
        photo_half += _found(photo_detector, cv2.imdecode(data, _HALF), None)
    out.update(photo_markers_full=photo_full, photo_markers_half=photo_half, **_charuco_corners())
    print(f"decode: full-frame CONTOUR search {c_full:.3f} ms a frame, at half size {c_half:.3f} "
          f"({c_half / c_full:.2f}x); marker found in {found_full} / {found_half} of {len(frames)} frames; "
          f"real photos (tests/data/opencv_contrib): {photo_full} markers found at full size, {photo_half} at half")
    print(f"decode: the 68 ChArUco markers of img_00-03: our corners' error against the board's {out['charuco_median_px']:.2f} "
          f"px median (p90 {out['charuco_p90_px']:.2f}) on {out['charuco_found']} markers; the half-size search finds "
          f"{out['charuco_found_half']} of them")
    return out


if __name__ == "__main__":
    main()

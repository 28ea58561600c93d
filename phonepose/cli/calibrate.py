"""``phonepose board``, ``phonepose marker``, ``phonepose calibrate-camera``: printables and camera
calibration for real recordings (docs/calibration.md)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import typer
from rich.console import Console
from rich.table import Table

from phonepose.cli import app
from phonepose.cli.options import QUIET, QUIET_ACCEPTED, Paper, number
from phonepose.cli.output import print_table, stdout_console
from phonepose.errors import ConfigError
from phonepose.files import check_input, check_output, write_text_output

MAX_IMAGE_SIDE_PX = 20_000   # a marker image larger than this is no screen's and would take gigabytes
MAX_CAMERA_INDEX = 1023      # cv2.VideoCapture's index (V4L2 /dev/videoN); -1 ("any") crashes OpenCV here

DEFAULT_SPEC = "charuco squares=7x5 square_mm=30 marker_mm=22 dictionary=DICT_5X5_100"


PNG: dict[str, Any] = dict(suffixes=(".png",), what="a PNG image")


@app.command("board")
def board(
    out: Path = typer.Option(..., "--out", "-o", help="PNG file to write."),
    spec: str = typer.Option(DEFAULT_SPEC, "--board", help="Board description: squares=CxR (2..100 each) square_mm= "
                             "(1..500) marker_mm= (less than square_mm, and at least one pixel per marker cell at --dpi) "
                             "dictionary= (keys left out keep the default)."),
    dpi: int = typer.Option(300, "--dpi", callback=number(50, 1200, integer=True),
                            help="Print resolution (50..1200); the PNG records it. A page has at most 300 Mpx "
                                 "(A3 at 1200 dpi)."),
    paper: Paper = typer.Option(Paper.a4, "--paper", case_sensitive=False,
                                help="a4, a3, letter (landscape) or fit (board + margin)."),
) -> None:
    """Write the ChArUco calibration board as a printable PNG, true sizes on the margin.

    Print it at 100 % (no "fit to page") and check the squares with a ruler.

    Example: [bold]phonepose board --out board.png[/bold]
    """
    from phonepose.calibration.board import board_png, board_spec, parse_board_spec, px_per_mm

    b = parse_board_spec(spec)
    check_output(out, "out", **PNG)
    write_text_output(out, board_png(b, dpi, paper.value), "out", **PNG)
    typer.echo(f"{out}: {board_spec(b)}, {b.size_mm[0]:g} x {b.size_mm[1]:g} mm on {paper.value} at {dpi} dpi "
               f"(square = {b.square_mm * px_per_mm(dpi):.1f} px); print at 100 % and check a square measures "
               f"{b.square_mm:g} mm")


@app.command("marker")
def marker(
    out: Path = typer.Option(..., "--out", "-o", help="PNG file to write."),
    dictionary: str = typer.Option("DICT_4X4_50", "--dictionary", help="ArUco dictionary (the simulator's: DICT_4X4_50)."),
    marker_id: int = typer.Option(7, "--id", callback=number(0, integer=True), help="Marker id (the simulator's: 7)."),
    pixels: int = typer.Option(400, "--pixels", callback=number(1, MAX_IMAGE_SIDE_PX, integer=True),
                               help="Side of the marker (black border included) in pixels."),
    quiet_zone: int | None = typer.Option(None, "--quiet-zone", callback=number(0, MAX_IMAGE_SIDE_PX, integer=True),
                                             help="White margin in pixels (default: one bit cell)."),
) -> None:
    """Write the controller's ArUco marker as a PNG (what the phone shows on its screen).

    Example: [bold]phonepose marker --out marker.png[/bold]
    """
    import cv2

    from phonepose.calibration.marker_image import marker_image

    image = marker_image(dictionary.upper(), marker_id, pixels, 1, quiet_zone)
    ok, buf = cv2.imencode(".png", image)
    write_text_output(out, buf.tobytes(), "out", **PNG)
    margin = (image.shape[0] - pixels) // 2
    typer.echo(f"{out}: {dictionary.upper()} id {marker_id}, marker {pixels} px + {margin} px white margin "
               f"({image.shape[1]}x{image.shape[0]} px); its black square is what the session's marker size measures")


@app.command("calibrate-camera")
def calibrate_camera(
    out: Path = typer.Option(..., "--out", "-o", help="Calibration file to write (OpenCV YAML, read by "
                             "`record live --calibration`)."),
    device: int | None = typer.Option(None, "--camera", callback=number(0, MAX_CAMERA_INDEX, integer=True),
                                         help="Capture live from camera N (cv2.VideoCapture index, as "
                                              "`record live --camera N`)."),
    video: Path | None = typer.Option(None, "--video", help="A video of the board."),
    images: Path | None = typer.Option(None, "--images", help="A directory of photos of the board."),
    spec: str = typer.Option(DEFAULT_SPEC, "--board", help="The board that was filmed (as `phonepose board --board`)."),
    max_views: int = typer.Option(40, "--max-views", callback=number(1, 1000, integer=True),
                                  help="Use at most this many views (evenly spread)."),
    min_corners: int = typer.Option(8, "--min-corners", callback=number(4, 10_000, integer=True),
                                    help="A frame is a view if it shows at least this many board corners."),
    seconds: float = typer.Option(120.0, "--seconds", callback=number(0, 24 * 3600, lo_open=True, unit="s"),
                                  help="--camera: stop capturing after this long."),
    size: str | None = typer.Option(None, "--size", help="--camera: ask for WxH frames (e.g. 1280x720); "
                                       "calibrate at the resolution you record at."),
    quiet: bool = typer.Option(False, "--quiet", "-q", **QUIET),
) -> None:
    """Calibrate a camera (intrinsics + plumb_bob distortion) from views of the ChArUco board.

    Give exactly one of --camera N, --video FILE, --images DIR.

    Example: [bold]phonepose calibrate-camera --video board.mp4 --out cam.yaml[/bold]
    """
    import numpy as np

    from phonepose.calibration.board import board_spec, parse_board_spec
    from phonepose.calibration.calibrate import RECOMMENDED_VIEWS
    from phonepose.calibration.calibrate import calibrate_camera as run
    from phonepose.calibration.camera_file import OPENCV_FORMATS, OPENCV_WHAT, save_calibration

    err = Console(stderr=True)
    b = parse_board_spec(spec)
    device_size = None
    if size is not None:
        try:
            w, h = (int(v) for v in size.lower().split("x"))
            if w <= 0 or h <= 0:
                raise ValueError
        except ValueError:
            raise ConfigError(f"--size {size!r}: expected WIDTHxHEIGHT, e.g. 1280x720") from None
        if device is None:
            raise ConfigError("--size applies to --camera only (a video or photos have their own size)")
        device_size = (w, h)
    inputs = [video] if video is not None else []
    check_output(out, "out", inputs=inputs, suffixes=tuple(OPENCV_FORMATS), what=OPENCV_WHAT)  # before the capture
    t0 = time.perf_counter()
    result = run(images=images, video=video, device=device, board=b, max_views=max_views,
                 min_corners=min_corners, device_seconds=seconds, device_size=device_size,
                 progress=None if quiet else (lambda line: err.print(line, style="dim", markup=False, highlight=False)))
    save_calibration(out, result.to_file(), inputs=inputs)
    wall = time.perf_counter() - t0

    for line in result.skipped:
        typer.echo(f"phonepose: warning: {line}", err=True)
    K, D, s = result.K, result.D, result.std_intrinsics
    table = Table(title=f"{out}: {result.width}x{result.height} px", title_justify="left")
    table.add_column("")
    table.add_column("value", justify="right")
    table.add_column("± 1σ", justify="right")
    pv = result.per_view_rms_px
    worst = int(pv.argmax())
    table.add_row("RMS reprojection error", f"{result.rms_px:.3f} px", "")
    table.add_row("per-view RMS median / max", f"{float(np.median(pv)):.3f} / {pv.max():.3f} px",
                  f"worst: {result.views[worst]}")
    table.add_row("views used", f"{len(result.views)}",
                  f"{result.frames_with_board} with board / {result.frames_examined} read")
    table.add_row("corners per view (median)", f"{float(np.median(result.corners_per_view)):g}",
                  f"of {b.n_corners}")
    for name, value, sd in (("fx", K[0, 0], s[0]), ("fy", K[1, 1], s[1]), ("cx", K[0, 2], s[2]), ("cy", K[1, 2], s[3])):
        table.add_row(f"{name} (px)", f"{value:.2f}", f"{sd:.2f}")
    for name, value, sd in zip(("k1", "k2", "p1", "p2", "k3"), D, (s[4], s[5], s[6], s[7], s[8]), strict=True):
        table.add_row(name, f"{value:+.5f}", f"{sd:.5f}")
    table.caption = board_spec(b)
    print_table(stdout_console(), table)
    notes = []
    if len(result.views) < RECOMMENDED_VIEWS:
        notes.append(f"only {len(result.views)} views: {RECOMMENDED_VIEWS}-40 from different angles give a steadier result")
    if result.rms_px > 1.0:
        notes.append(f"RMS {result.rms_px:.2f} px is high (expect < 0.5 px): blurred frames or a wrong --board")
    if s[0] > 0.01 * K[0, 0]:
        notes.append(f"fx is uncertain (± {s[0]:.1f} px): add views with the board tilted and near the image corners")
    for note in notes:
        typer.echo(f"phonepose: warning: {note}", err=True)
    typer.echo(f"{out}: written in {wall:.1f} s")


@app.command("calibrate-hand-eye")
def calibrate_hand_eye(
    session: Path = typer.Argument(..., help="A session with the controller's VIO and motion-capture ground truth."),
    out: Path = typer.Option(..., "--out", "-o", help="Calibration file to write (YAML, read by "
                             "`playback --gt-calibration`)."),
    translation: str = typer.Option("0,0,0", "--translation", help="The rigid body's origin in the phone's frame, "
                                    "metres x,y,z, measured (it is not estimated: see docs/evaluation.md)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", **QUIET_ACCEPTED),
) -> None:
    """Estimate the mocap rigid body's rotation against the phone's frame, and the mocap clock's offset, from one session.

    Uses the controller's own VIO and the motion-capture ground truth (docs/evaluation.md).

    Example: [bold]phonepose calibrate-hand-eye s.mcap --out he.yaml && phonepose playback s.mcap --gt-calibration he.yaml[/bold]
    """
    import numpy as np

    from phonepose.calibration.hand_eye import hand_eye_from_session, save_hand_eye

    try:
        lever = [float(v) for v in translation.split(",")]
        if len(lever) != 3 or not np.isfinite(lever).all() or max(abs(v) for v in lever) > 1:
            raise ValueError
    except ValueError:
        raise ConfigError(f"--translation {translation!r}: expected x,y,z in metres (each within +-1), "
                          "e.g. 0.01,0,-0.005") from None
    from phonepose.calibration.gt_calibration import SUFFIXES, WHAT

    check_input(session, "session")
    check_output(out, "out", inputs=[session], suffixes=SUFFIXES, what=WHAT)
    he = hand_eye_from_session(session, translation=lever)
    save_hand_eye(out, he, inputs=[session], session=session.name)
    rv = he.T_controller_mocap.rotation.as_rotvec(degrees=True)
    typer.echo(f"{out}: rigid body turned {he.rotation_deg:.2f} ± {he.sigma_rotation_deg:.2f} deg from the phone's frame "
               f"(rotation vector {rv[0]:+.2f} {rv[1]:+.2f} {rv[2]:+.2f} deg), mocap clock {he.time_offset_s * 1e3:+.0f} "
               f"± {he.sigma_time_offset_ms:.1f} ms (1σ); {he.pairs} motions, residual {he.residual_deg:.2f} deg RMS")
    for line in he.warnings:
        typer.echo(f"phonepose: warning: {line}", err=True)


def _gt_table(out: Path, cal) -> Table:
    """What calibrate-gt found, each quantity with its 1σ (docs/calibration.md#reading-the-result)."""
    import numpy as np

    s = cal.sigma
    table = Table(title=f"{out}: {cal.samples} marker sightings, residual {cal.residual_mm:.2f} mm / "
                        f"{cal.residual_deg:.2f} deg RMS", title_justify="left")
    table.add_column("")
    table.add_column("value", justify="right")
    table.add_column("± 1σ", justify="right")

    def sd(key: str, unit: str) -> str:
        return f"{s[key]:.2f} {unit}" if key in s else ""

    table.add_row("clock offset (gt - recorder)", f"{cal.time_offset_s * 1e3:+.1f} ms", sd("sigma_time_offset_ms", "ms"))
    for name, pose, rot_key, trans_key in (("world -> camera", cal.T_world_camera, "sigma_world_rotation_deg",
                                            "sigma_world_translation_mm"),
                                           ("grip -> body", cal.T_controller_gt, "sigma_body_rotation_deg",
                                            "sigma_body_translation_mm")):
        if pose is None:
            continue
        rv = pose.rotation.as_rotvec(degrees=True)
        t = np.asarray(pose.translation) * 1e3
        table.add_row(f"{name} rotation", f"{np.linalg.norm(rv):.2f} deg ({rv[0]:+.2f} {rv[1]:+.2f} {rv[2]:+.2f})",
                      sd(rot_key, "deg"))
        table.add_row(f"{name} translation", f"{np.linalg.norm(t):.1f} mm ({t[0]:+.1f} {t[1]:+.1f} {t[2]:+.1f})",
                      sd(trans_key, "mm"))
    return table


@app.command("calibrate-gt")
def calibrate_gt(
    session: Path = typer.Argument(..., help="A session with camera frames showing the phone's marker and a ground truth."),
    out: Path = typer.Option(..., "--out", "-o", help="Calibration file to write (YAML, read by "
                             "`playback --gt-calibration`)."),
    gt: Path | None = typer.Option(None, "--gt", help="Ground truth from a trajectory file (TUM, or EuRoC "
                                      ".csv) instead of the session's /gt/controller/pose; its clock may be off."),
    gt_format: str | None = typer.Option(None, "--gt-format", help="tum or euroc (default: euroc for .csv, else tum)."),
    max_offset: float = typer.Option(0.5, "--max-offset", callback=number(0, 5, lo_open=True, unit="s"),
                                     help="Search the ground truth's clock offset within +- this (s)."),
    bootstrap: int = typer.Option(200, "--bootstrap", callback=number(0, 10_000, integer=True),
                                  help="Resamples for the uncertainties (0: none)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", **QUIET_ACCEPTED),
) -> None:
    """Estimate the ground truth's clock offset, its world in the display camera and the tracked body on the phone.

    From the session alone: the display camera's sightings of the phone's marker against the ground truth
    (A X = Z B, closed form then least squares); each quantity with its 1σ (docs/calibration.md).

    Example: [bold]phonepose calibrate-gt s.mcap --out gt.yaml && phonepose playback s.mcap --gt-calibration gt.yaml[/bold]
    """
    from phonepose.calibration.calibrate_gt import calibrate_gt_session
    from phonepose.calibration.ground_truth import gt_format_of
    from phonepose.calibration.gt_calibration import SUFFIXES, WHAT, save_gt_calibration

    check_input(session, "session")
    inputs = [session] + ([gt] if gt is not None else [])
    if gt is not None:
        check_input(gt, "ground-truth file")
        gt_format_of(gt, gt_format)
    elif gt_format is not None:
        raise ConfigError("--gt-format applies to --gt FILE only")
    check_output(out, "out", inputs=inputs, suffixes=SUFFIXES, what=WHAT)
    t0 = time.perf_counter()
    cal = calibrate_gt_session(session, gt, gt_format=gt_format, max_offset_s=max_offset, bootstrap=bootstrap)
    save_gt_calibration(out, cal, inputs=inputs)
    print_table(stdout_console(), _gt_table(out, cal))
    for line in cal.warnings:
        typer.echo(f"phonepose: warning: {line}", err=True)
    typer.echo(f"{out}: written in {time.perf_counter() - t0:.1f} s")

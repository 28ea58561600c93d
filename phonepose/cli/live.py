"""``phonepose record live``: record a webcam (the display camera) and a phone's page (the controller)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import typer

from phonepose.cli.options import QUIET, CorrectionMath, number
from phonepose.cli.output import progress_lines, takes_unicode
from phonepose.cli.record import record_app
from phonepose.errors import ConfigError
from phonepose.numbers import RATE_MAX_HZ, RATE_MIN_HZ

LIVE_TRACKER_HELP = ("Run this tracker live (repeatable; as playback's --tracker: a name, module:Class, an entry "
                     "point, all): its estimates go into the session (/trackers/<name>/pose) and to the pose stream.")
POSE_HOST_HELP = ("Address the pose stream listens on (default loopback; another address opens it to the network: "
                  "wss:// and the phone page's token).")
POSE_PORT_HELP = "Port of the pose stream (ws://HOST:PORT/poses; 0: any free port)."


def live_tracking(tracker: list[str], rate: float, correction_math: str, pose_host: str, pose_port: int):
    """The live trackers asked for (None without -t); unknown names fail here, before anything starts."""
    if not tracker:
        return None
    from phonepose.pipeline.trackers import make_trackers
    from phonepose.record.live.session import LiveTracking

    if not 0 <= pose_port <= 65535:
        raise ConfigError(f"--pose-port {pose_port}: expected 0..65535")
    return LiveTracking(make_trackers(tracker, correction_math), rate_hz=rate, correction_math=correction_math,
                        pose_host=pose_host, pose_port=pose_port)


@record_app.command("live")
def live(
    out: Path = typer.Option(..., "--out", "-o", help="Session file to write (.mcap)."),
    camera: str = typer.Option("0", "--camera", help="Camera device index (0, 1, ...) or a video file."),
    calibration: Path = typer.Option(..., "--calibration", help="The camera's calibration file "
                                     "(`phonepose calibrate-camera`, OpenCV YAML)."),
    host: str = typer.Option("0.0.0.0", "--host", help="Address to listen on (0.0.0.0: every interface)."),
    port: int = typer.Option(8443, "--port", help="HTTPS port the phone connects to (0: any free port)."),
    tls_dir: Path | None = typer.Option(None, "--tls-dir", help="Where the self-signed certificate is kept "
                                           "(default ~/.config/phonepose/tls)."),
    marker_size: float | None = typer.Option(None, "--marker-size", help="The marker's side on the phone screen in "
                                                "metres, measured with a ruler (default: what the page reports)."),
    dictionary: str = typer.Option("DICT_4X4_50", "--marker-dictionary", help="ArUco dictionary the page shows."),
    marker_id: int = typer.Option(7, "--marker-id", help="Marker id the page shows."),
    duration: float | None = typer.Option(None, "--duration", help="Stop after this many seconds."),
    pace: bool = typer.Option(True, "--pace/--no-pace", help="Video file: read in real time (default) or as fast "
                              "as possible (camera-only tests; a phone's samples only line up with a paced video)."),
    rerun: Path | None = typer.Option(None, "--rerun", help="Also log what is recorded to this Rerun .rrd file."),
    spawn: bool = typer.Option(False, "--spawn", help="Also stream what is recorded to a Rerun viewer (live preview)."),
    gt_controller: str = typer.Option("right", "--gt-controller", help="Which headset controller is fixed to the phone "
                                      "(right or left): its grip pose is the ground truth (/gt/controller/pose), the "
                                      "other one's goes to /gt/board_controller/pose."),
    qr: bool = typer.Option(True, "--qr/--no-qr", help="Print the pages' URLs as QR codes too."),
    force: bool = typer.Option(False, "--force", help="Replace --out if it exists (without it, an existing "
                               "recording is an error and stays untouched)."),
    tracker: list[str] = typer.Option([], "--tracker", "-t", help=LIVE_TRACKER_HELP),
    rate: float = typer.Option(20.0, "--rate", callback=number(RATE_MIN_HZ, RATE_MAX_HZ, unit="Hz"),
                               help="Live trackers' ticks per second (as playback's --rate)."),
    correction_math: CorrectionMath = typer.Option(CorrectionMath.paper, "--correction-math", case_sensitive=False,
                                                   help="Live trackers: paper (equations 1-6) or se3."),
    pose_host: str = typer.Option("127.0.0.1", "--pose-host", help=POSE_HOST_HELP),
    pose_port: int = typer.Option(8765, "--pose-port", help=POSE_PORT_HELP),
    quiet: bool = typer.Option(False, "--quiet", "-q", **QUIET),
) -> None:
    """Record a live session: webcam frames and, from a phone's browser page (WebXR on ARCore
    phones), its 6DoF pose, IMU and the anchor you set by tapping with the phone in view; and, from a
    WebXR headset's browser (the second link), the ground truth: the pose of its controller fixed to the phone.

    Example: [bold]phonepose record live --camera 0 --calibration cam.yaml --out s.mcap --spawn[/bold]

    Open the printed URL on the phone (same network; accept the certificate warning once), tap
    [bold]Start AR[/bold], hold the phone's screen in the camera's view and tap [bold]Anchor[/bold].
    Ctrl-C or SIGTERM stop the recording and leave a valid file. Guide: docs/recording-real-sessions.md.
    """
    from phonepose.files import OutputPlan

    if rerun is not None and spawn:
        raise ConfigError("use either --rerun FILE or --spawn, not both")
    tracking = live_tracking(tracker, rate, correction_math.value, pose_host, pose_port)
    # the output rule (phonepose.files), as `record sim` follows it: a new recording is written under its own name,
    # created exclusively and locked while it is written, so that no other phonepose (a `recover --force`, a second
    # `record live --force`) can replace it under the running recorder; over an existing file, --force writes a
    # temporary that replaces it only when this recording is complete
    video = [Path(camera)] if not camera.isdigit() and Path(camera).is_file() else []
    plan = OutputPlan(inputs=[calibration, *video])
    session_out = plan.file(out, "out", what="an MCAP session", in_place=True, force=force)
    rrd = plan.file(rerun, "rerun", suffixes=(".rrd",), what="a Rerun recording") if rerun is not None else None
    with plan:                          # every check first, before the server starts
        assert session_out.tmp is not None   # the plan's block made it
        result, wall = _record(session_out.tmp, out, camera, calibration, host=host, port=port, tls_dir=tls_dir,
                               dictionary=dictionary, marker_id=marker_id, marker_size=marker_size, duration=duration,
                               pace=pace, rerun=rrd.tmp if rrd is not None else None, spawn=spawn, qr=qr,
                               gt_controller=gt_controller, tracking=tracking, quiet=quiet)
    r, c = result.record, result.counts
    from phonepose.schemas.topics import Topic

    status = "interrupted, file is valid" if r.interrupted else f"{result.stop_reason}, done"
    typer.echo(f"{out}: {r.duration_ns / 1e9:.1f} s, {r.frames} frames, {c.get(Topic.CONTROLLER_VIO_POSE, 0)} poses, "
               f"{c.get(Topic.CONTROLLER_IMU, 0)} IMU samples, {c.get(Topic.CONTROLLER_ANCHOR, 0)} anchors, "
               f"{c.get(Topic.GT_CONTROLLER_POSE, 0)} ground-truth poses, "
               f"{r.messages} messages in {wall:.1f} s; {status}")
    for line in result.tracking:
        typer.echo(line)
    for line in result.summary[1:]:
        typer.echo(f"warning: {line}", err=True)


def _record(path: Path, out: Path, camera: str, calibration: Path, *, host: str, port: int, tls_dir: Path | None,
            dictionary: str, marker_id: int, marker_size: float | None, duration: float | None, pace: bool,
            rerun: Path | None, spawn: bool, qr: bool, gt_controller: str, tracking=None, quiet: bool = False):
    """The recording into ``path`` (the output plan's file for ``out``, the name the user reads)."""
    from phonepose.record.live import LiveSession

    echo = progress_lines(quiet, stamp=True)

    session = LiveSession(path, camera, calibration, host=host, port=port, tls_dir=tls_dir, dictionary=dictionary,
                          marker_id=marker_id, marker_size_m=marker_size, duration_s=duration, pace=pace,
                          rerun_path=rerun, spawn=spawn, echo=echo, gt_controller=gt_controller, tracking=tracking)
    url = session.start()
    cert = session.certificate
    if cert.broken:
        typer.echo(f"phonepose: warning: the TLS certificate in {cert.cert_path.parent} could not be used "
                   f"({cert.broken}); made a new one", err=True)
    typer.echo(f"{'created' if cert.created else 'using'} the self-signed certificate {cert.cert_path} "
               f"(SHA-256 {cert.sha256})", err=True)
    typer.echo(f"recording to {out}: open this page on the phone (same network; accept the certificate warning):")
    typer.echo(f"  {url}")
    if qr:
        print_qr(url)
    typer.echo(f"ground truth (optional): open this page in the headset's browser, its {gt_controller} controller "
               "fixed to the phone:")
    typer.echo(f"  {session.headset_url}")
    if qr:
        print_qr(session.headset_url)
    if session.source.pose_server is not None:
        typer.echo(f"live trackers {', '.join(t.name for t in tracking.trackers)}: pose stream at "
                   f"{session.source.pose_server.url}")
    typer.echo("Ctrl-C stops the recording.", err=True)
    sys.stdout.flush()
    t0 = time.perf_counter()
    result = session.run()
    return result, time.perf_counter() - t0


def print_qr(url: str) -> None:
    """``url`` as a QR code on standard output: half blocks (compact) where the terminal takes them, else
    coloured spaces (a C or latin-1 locale would show the blocks as \\u2580 escapes: no code at all)."""
    import segno

    segno.make(url, error="m").terminal(out=sys.stdout, compact=takes_unicode(sys.stdout))

#!/usr/bin/env python
"""Screenshots of what a user sees in Rerun's web viewer, rendered headless.

    python tools/screenshot.py playback.rrd --out docs/images/playback.png --theme both
    python tools/screenshot.py session.mcap --out docs/images/session.png --theme light

Serves the ``.rrd`` (or a session ``.mcap``, which the viewer imports as it would for
``rerun session.mcap``) with ``rerun --serve-web`` on 127.0.0.1, opens the web viewer in headless
Chromium with software GL (SwiftShader through ANGLE: no GPU needed), waits until the rendered
page stops changing (two identical screenshots in a row; the software renderer needs ~30 s on a
loaded 2-core machine) and saves it. ``--theme light|dark|both`` sets the page's
``prefers-color-scheme``, which the viewer follows; ``both`` writes ``NAME-light.png`` and
``NAME-dark.png``. The viewer opens a finished recording at its end: every trajectory and
error series is complete there.

Needs Debian's ``chromium`` (or ``CHROMIUM=/path``) and playwright (the test extra);
docs/playback.md, "Screenshots", says how the README's images were made.
"""

from __future__ import annotations

import argparse
import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.parse
import urllib.request
from pathlib import Path

CHROMIUM_ARGS = [
    "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",   # software WebGL
    "--no-sandbox", "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--no-first-run",
]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _rerun_cli() -> str:
    exe = Path(sys.executable).parent / "rerun"
    found = str(exe) if exe.exists() else shutil.which("rerun")
    if not found:
        sys.exit("screenshot: error: no `rerun` command (pip install rerun-sdk)")
    return found


def _wait_http(url: str, deadline: float) -> None:
    while True:
        try:
            with urllib.request.urlopen(url, timeout=5):
                return
        except OSError:
            if time.monotonic() > deadline:
                sys.exit(f"screenshot: error: the web viewer at {url} did not answer")
            time.sleep(0.5)


def shoot(source: Path, outputs: dict[str, Path], *, width: int, height: int, timeout_s: float,
          settle_s: float) -> None:
    from playwright.sync_api import sync_playwright

    web_port, grpc_port = _free_port(), _free_port()
    env = dict(os.environ, RERUN_ANALYTICS="0")
    server = subprocess.Popen([_rerun_cli(), "--serve-web", str(source), "--bind", "127.0.0.1",
                               "--web-viewer-port", str(web_port), "--port", str(grpc_port)],
                              env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              start_new_session=os.name == "posix")   # `rerun` is a wrapper: stop its viewer too
    try:
        deadline = time.monotonic() + timeout_s
        base = f"http://127.0.0.1:{web_port}"
        _wait_http(base, deadline)
        url = f"{base}/?url={urllib.parse.quote(f'rerun+http://127.0.0.1:{grpc_port}/proxy', safe='')}"
        chromium = os.environ.get("CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS, headless=True)
            try:
                for theme, out in outputs.items():
                    page = browser.new_page(viewport={"width": width, "height": height}, color_scheme=theme)
                    page.goto(url)
                    previous = None
                    while True:   # settled: two screenshots settle_s apart are identical
                        time.sleep(settle_s)
                        png = page.screenshot(timeout=max(1.0, deadline - time.monotonic()) * 1000)
                        if png == previous:
                            break
                        if time.monotonic() > deadline:
                            print(f"screenshot: warning: {out} still changing after {timeout_s:g} s; saved as it was",
                                  file=sys.stderr)
                            break
                        previous = png
                    out.parent.mkdir(parents=True, exist_ok=True)
                    out.write_bytes(png)
                    print(out)
                    page.close()
            finally:
                browser.close()
    finally:
        _stop(server)


def _stop(server: subprocess.Popen) -> None:
    """Stop the server and the viewer binary the ``rerun`` wrapper started (its process group on POSIX)."""
    if os.name != "posix":
        server.terminate()
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            server.kill()
        return
    import signal

    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(server.pid, sig)
        except ProcessLookupError:     # the whole group is gone
            return
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            server.poll()
            try:
                os.killpg(server.pid, 0)
            except ProcessLookupError:
                return
            time.sleep(0.2)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("source", type=Path, help="a .rrd recording or a session .mcap")
    ap.add_argument("--out", type=Path, required=True, help="PNG to write (with --theme both: NAME-light/-dark.png)")
    ap.add_argument("--theme", choices=["light", "dark", "both"], default="both")
    ap.add_argument("--size", default="1600x1000", help="viewport WIDTHxHEIGHT (default 1600x1000)")
    ap.add_argument("--timeout", type=float, default=900.0, help="give up waiting after this many seconds")
    ap.add_argument("--settle", type=float, default=10.0, help="seconds between the compared screenshots")
    args = ap.parse_args(argv)
    if not args.source.is_file():
        sys.exit(f"screenshot: error: {args.source}: no such file")
    width, height = (int(v) for v in args.size.lower().split("x"))
    themes = ["light", "dark"] if args.theme == "both" else [args.theme]
    outputs = {t: (args.out.with_name(f"{args.out.stem}-{t}{args.out.suffix}") if args.theme == "both" else args.out)
               for t in themes}
    shoot(args.source, outputs, width=width, height=height, timeout_s=args.timeout,
          settle_s=args.settle)


if __name__ == "__main__":
    main()

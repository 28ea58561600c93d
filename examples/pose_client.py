"""Read the live trackers' pose stream (``phonepose record live -t T8``) and print one line per estimate.

    python examples/pose_client.py ws://127.0.0.1:8765/poses
    python examples/pose_client.py "wss://192.168.1.20:8765/poses?token=..." --insecure   # opened to the network

Each message is one JSON line: t_ns (the tick, recorder clock), tracker, position [x, y, z] (m, display_vio) and
quaternion [x, y, z, w] (null when the tracker has no pose), in_view (the marker recognised), published_ns.
"""

import argparse
import asyncio
import json

import aiohttp


async def main(url: str, insecure: bool, count: int) -> None:
    async with aiohttp.ClientSession() as session, session.ws_connect(url, ssl=False if insecure else None) as ws:
        seen = 0
        async for msg in ws:
            if msg.type != aiohttp.WSMsgType.TEXT:
                break
            p = json.loads(msg.data)
            where = "no pose" if p["position"] is None else " ".join(f"{v:+.3f}" for v in p["position"])
            print(f"{p['t_ns']} {p['tracker']} {where} in_view={p['in_view']}", flush=True)
            seen += 1
            if seen == count:
                break


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("url", help="the pose stream's URL, as record live prints it")
    ap.add_argument("--insecure", action="store_true", help="accept the recorder's self-signed certificate (wss)")
    ap.add_argument("--count", type=int, default=0, help="stop after this many lines (default: until the end)")
    args = ap.parse_args()
    asyncio.run(main(args.url, args.insecure, args.count))

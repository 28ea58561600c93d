"""Wall and CPU time of one playback by two versions of phonepose, alternated (speed work on a noisy host).

    git archive <rev> phonepose | tar -x -C OLD
    python tools/playback_pairs.py OLD exp1.mcap [--rounds 3] [--trackers all]

Each round plays the session once with the phonepose in OLD and once with this checkout's, each in a fresh
interpreter started outside the checkout (so that OLD is the one imported), after an untimed warm-up
playback of a 2 s hand-made session; the two outputs must be the same to the byte (every trajectory and
metrics.json). docs/performance.md, "Issue 23, eighth round", timed the decode thread with it.
"""

from __future__ import annotations

import argparse
import filecmp
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

_CHILD = r"""
import json, sys, time
from pathlib import Path
from phonepose.playback.engine import run_playback
from phonepose.testing.playback_session import write_test_session
session, out, trackers = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
warm = out.parent / (out.name + "-warm.mcap")
write_test_session(warm, duration_s=2.0)
run_playback(warm, trackers=trackers, out_dir=out.parent / (out.name + "-warm"))
t0, c0 = time.perf_counter(), time.process_time()
run_playback(session, trackers=trackers, out_dir=out)
import phonepose
print(json.dumps({"wall": time.perf_counter() - t0, "cpu": time.process_time() - c0,
                  "code": str(Path(phonepose.__file__).parent)}))
"""


def _play(code: Path, session: Path, out: Path, trackers: str) -> dict:
    env = dict(os.environ, PYTHONPATH=str(code))
    r = subprocess.run([sys.executable, "-c", _CHILD, str(session), str(out), trackers], env=env,
                       cwd=out.parent, capture_output=True, text=True, timeout=1800)
    if r.returncode != 0:
        raise SystemExit(f"error: playback with {code} failed: {(r.stderr.strip().splitlines() or ['?'])[-1]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def _same(a: Path, b: Path) -> bool:
    files = [f for f in sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file() and p.suffix in (".tum", ".json"))
             if f.name != "run.json"]
    return bool(files) and all((b / f).is_file() and filecmp.cmp(a / f, b / f, shallow=False) for f in files)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old", type=Path, help="a folder holding the other version's phonepose package")
    ap.add_argument("session", type=Path)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--trackers", default="all")
    args = ap.parse_args(argv)
    if not (args.old / "phonepose" / "__init__.py").is_file():
        print(f"error: {args.old} holds no phonepose package", file=sys.stderr)
        return 2
    new = Path(__file__).resolve().parent.parent
    with tempfile.TemporaryDirectory(prefix="playback-pairs-") as d:
        tmp = Path(d)
        for k in range(args.rounds):
            old = _play(args.old.resolve(), args.session.resolve(), tmp / f"old{k}", args.trackers)
            cur = _play(new, args.session.resolve(), tmp / f"new{k}", args.trackers)
            same = _same(tmp / f"old{k}", tmp / f"new{k}")
            if k == 0:
                print(f"old from {old['code']}, new from {cur['code']}")
            print(f"round {k + 1}: old {old['wall']:.2f} s wall ({old['cpu']:.2f} s CPU), "
                  f"new {cur['wall']:.2f} s ({cur['cpu']:.2f} s CPU); outputs the same: {same}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

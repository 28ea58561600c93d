"""Run every benchmark side by side: ``python -m bench [name ...]``.

Each ``bench/bench_<name>.py`` has ``main() -> dict`` that measures our code next to its
floor or the tool a user would pick instead, in the same run, and prints ratios (machines
are shared and noisy: compare within a run, never across runs). Figures go to
docs/performance.md.
"""

from __future__ import annotations

import importlib
import json
import pathlib
import platform
import sys


def main(argv: list[str]) -> int:
    here = pathlib.Path(__file__).parent
    names = argv or sorted(p.stem.removeprefix("bench_") for p in here.glob("bench_*.py"))
    results = {"machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine(),
                           "cores": __import__("os").cpu_count()}}
    for name in names:
        print(f"\n=== {name} ===", flush=True)
        mod = importlib.import_module(f"bench.bench_{name}")
        results[name] = mod.main()
    out = here / "results.json"
    out.write_text(json.dumps(results, indent=2))
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

"""Run the benchmarks and write one JSON per benchmark.

    python -m bench.run_all --out bench/results [--only NAME ...] [--quick] [--timeout S]

Every `bench/bench_<name>.py` exposes `run(out_dir: Path, quick: bool) -> dict`. Each one runs
in its own Python process, so a benchmark that raises, crashes or hangs cannot stop the
others: its `<out>/<name>.json` then records the error. A result may hold a `targets` dict
of `{"value", "target", "met"}` entries; the summary counts the targets met. The exit code is
1 when a benchmark failed or missed a target.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
import traceback
from datetime import UTC, datetime
from importlib import import_module
from pathlib import Path

BENCH_DIR = Path(__file__).resolve().parent
REPO = BENCH_DIR.parent


def discover() -> list[str]:
    """Names of the benchmarks: `bench_<name>.py` files beside this one, sorted."""
    return sorted(p.stem.removeprefix("bench_") for p in BENCH_DIR.glob("bench_*.py"))


def _machine() -> dict:
    return {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpus": os.cpu_count(),
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
    }


def _write(out: Path, name: str, record: dict) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps(record, indent=2, default=str) + "\n")


def run_inline(name: str, out: Path, quick: bool) -> dict:
    """Import bench_<name> and run it in this process; the record is written and returned."""
    record: dict = {
        "name": name,
        "quick": quick,
        "started": datetime.now(UTC).isoformat(timespec="seconds"),
        "machine": _machine(),
    }
    t0 = time.perf_counter()
    try:
        module = import_module(f"bench.bench_{name}")
        record["result"] = module.run(out, quick)
        record["ok"] = True
    except Exception as exc:  # noqa: BLE001 - a failing benchmark is recorded, not raised
        record["ok"] = False
        record["error"] = f"{type(exc).__name__}: {exc}"
        record["traceback"] = traceback.format_exc()
    record["seconds"] = round(time.perf_counter() - t0, 2)
    _write(out, name, record)
    return record


def run_isolated(name: str, out: Path, quick: bool, timeout: float | None) -> dict:
    """Run one benchmark in a child process; record a crash or a timeout as its error."""
    cmd = [sys.executable, "-m", "bench.run_all", "--out", str(out), "--only", name, "--inline"]
    if quick:
        cmd.append("--quick")
    target = out / f"{name}.json"
    target.unlink(missing_ok=True)
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, cwd=REPO, timeout=timeout, check=False)
        problem = None if target.exists() else f"process exited with code {proc.returncode} without a result"
    except subprocess.TimeoutExpired:
        problem = f"timed out after {timeout} s"
    if problem is None:
        return json.loads(target.read_text())
    record = {
        "name": name,
        "quick": quick,
        "ok": False,
        "error": problem,
        "seconds": round(time.perf_counter() - t0, 2),
    }
    _write(out, name, record)
    return record


def _targets(record: dict) -> tuple[int, int]:
    targets = (record.get("result") or {}).get("targets") or {}
    met = sum(1 for t in targets.values() if isinstance(t, dict) and t.get("met"))
    return met, len(targets)


def summary_line(record: dict) -> str:
    name = record["name"]
    if not record.get("ok"):
        return f"{name:<12} FAILED  {record.get('seconds', 0):7.1f} s  {record.get('error', '')}"
    met, total = _targets(record)
    targets = f"targets {met}/{total} met" if total else "no targets"
    line = f"{name:<12} ok      {record.get('seconds', 0):7.1f} s  {targets}"
    headline = (record.get("result") or {}).get("headline")
    return f"{line}  {headline}" if headline else line


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.run_all", description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("bench/results"), help="folder for <name>.json")
    parser.add_argument(
        "--only", action="append", default=None, metavar="NAME", help="run only NAME (repeatable)"
    )
    parser.add_argument("--quick", action="store_true", help="smaller runs (smoke test)")
    parser.add_argument("--timeout", type=float, default=None, help="seconds allowed per benchmark")
    parser.add_argument("--inline", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)

    known = discover()
    names = known
    if args.only:
        wanted = [n.removeprefix("bench_").removesuffix(".py") for n in args.only]
        unknown = [n for n in wanted if n not in known]
        if unknown:
            print(f"unknown benchmark(s): {', '.join(unknown)}; known: {', '.join(known)}", file=sys.stderr)
            return 2
        names = wanted
    out = args.out.resolve()
    if args.inline:
        records = [run_inline(n, out, args.quick) for n in names]
        return 0 if all(r["ok"] for r in records) else 1

    records = []
    for name in names:
        print(f"== {name}", flush=True)
        records.append(run_isolated(name, out, args.quick, args.timeout))
    print("\nbenchmark    status   seconds  results")
    for r in records:
        print(summary_line(r))
    print(f"JSON in {out}")
    bad = [r for r in records if not r.get("ok") or _targets(r)[0] < _targets(r)[1]]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())

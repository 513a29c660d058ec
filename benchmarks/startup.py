"""How long `calib` takes to start, side by side in one run: `python -c "import typer, rich"` (the floor
any typer CLI pays), `calib --version`, `calib --help` and `calib <command> --help` for every command
and every sub-app's command, as the typer app lists them. Each is the median wall time of --repeats
fresh processes; the table gives its ratio to the typer + rich floor and flags rows over --limit
(0.5 s: issue 48's bar; help must not wait for numba, pandas, scipy or matplotlib to import).

    python benchmarks/startup.py [--repeats 5] [--limit 0.5] [--check]

--check exits 1 when a row is over the limit. Not a test: the numbers depend on the machine and its load.
"""
from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path


def _calib() -> list[str]:
    """The console script next to this Python (a virtualenv's bin/), else `python -m calib_cli`."""
    script = Path(sys.executable).with_name("calib")
    if script.is_file():
        return [str(script)]
    found = shutil.which("calib")
    return [found] if found else [sys.executable, "-m", "calib_cli"]


def _paths() -> list[tuple[str, ...]]:
    """Every command's path, groups before their commands, in the order `calib --help` lists them."""
    import typer
    import typer.main

    from calib_cli.cli import app

    root = typer.main.get_command(app)
    ctx = root.make_context("calib", ["--help"], resilient_parsing=True)

    def walk(group, prefix):
        for name in group.list_commands(ctx):
            cmd = group.get_command(ctx, name)
            yield (*prefix, name)
            if hasattr(cmd, "list_commands"):
                yield from walk(cmd, (*prefix, name))

    return list(walk(root, ()))


def _median_seconds(argv: list[str], repeats: int, env: dict[str, str]) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        r = subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
        times.append(time.perf_counter() - t0)
        if r.returncode != 0:
            raise SystemExit(f"{' '.join(argv)} exited {r.returncode}: {r.stderr.decode()[-500:]}")
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5, help="fresh processes per row (the median is shown)")
    ap.add_argument("--limit", type=float, default=0.5, help="seconds a row may take")
    ap.add_argument("--check", action="store_true", help="exit 1 when a row is over --limit")
    args = ap.parse_args()

    env = {**os.environ, "COLUMNS": "100"}
    calib = _calib()
    rows = [("python -c 'import typer, rich'", [sys.executable, "-c", "import typer, rich"]),
            ("calib --version", [*calib, "--version"]),
            ("calib --help", [*calib, "--help"])]
    rows += [(f"calib {' '.join(p)} --help", [*calib, *p, "--help"]) for p in _paths()]

    width = max(len(label) for label, _ in rows)
    print(f"median of {args.repeats} fresh processes each; Python {sys.version.split()[0]}, {os.cpu_count()} CPUs")
    print(f"{'command':<{width}}  {'seconds':>7}  {'x typer+rich':>12}")
    base, over = None, []
    for label, argv in rows:
        t = _median_seconds(argv, args.repeats, env)
        base = base or t
        flag = "  over the limit" if t > args.limit else ""
        if flag:
            over.append(label)
        print(f"{label:<{width}}  {t:7.3f}  {t / base:12.2f}{flag}", flush=True)
    print(f"{len(rows) - len(over)} of {len(rows)} under {args.limit:g} s"
          + (f"; over: {', '.join(over)}" if over else ""))
    if args.check and over:
        sys.exit(1)


if __name__ == "__main__":
    main()

"""A calibration's fits on this tree against an earlier revision, side by side: each tree refits one model
revision's rounds of a committed run from its results rows (nothing simulated: every heap is in the rows),
on a copy of the run, and prints its wall time, its peak memory and whether every table it wrote is the
committed one, bit for bit.

    python benchmarks/posterior_fits.py --baseline 83a2ee5 --run sample_runs/hidden-effect --revision 1

The command is the one the run's lock records for that revision (`calibrate/rev<N>.lock.json`), pointed at
the copy. The rounds' designs are kept (their locks are up to date), so each round learns from the heaps it
learnt from; the rounds' posteriors and the answer are computed again. The trees run one after the other,
the order swapped every repeat (these machines are noisy: use an even --repeats for a ratio).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd


def fresh_copy(run: Path, revision: int, dest: Path) -> None:
    """``run`` copied to ``dest`` with the revision's round posteriors and answer made stale."""
    shutil.copytree(run, dest, ignore=shutil.ignore_patterns("runs"))
    cal = dest / "calibrate"
    for lock in cal.glob(f"rev{revision}-round-*.lock.json"):
        if not lock.name.endswith("-design.lock.json"):
            lock.unlink()
    (cal / f"rev{revision}.lock.json").unlink()
    for f in (cal / f"rev{revision}").glob("round-*/summary.parquet"):
        f.unlink()


def refit(tree: Path, run: Path, revision: int, work: Path) -> tuple[float, float]:
    """(wall s, peak MB) of the revision's calibration refitted by ``tree`` on a copy of ``run`` at ``work``."""
    lock = json.loads((run / "calibrate" / f"rev{revision}.lock.json").read_text())
    args = shlex.split(lock["command"])[1:]
    args[args.index("--run") + 1] = str(work)
    fresh_copy(run, revision, work)
    env = {**os.environ, "PYTHONPATH": str(tree)}
    t = time.perf_counter()
    # the calibration's last check (rounds.parquet against the revision's lock) refuses the copy, whose lock
    # this made stale; every table is written before it
    with open(work.parent / f"{work.name}.log", "w") as log:
        proc = subprocess.Popen([sys.executable, "-m", "calib_cli", *args], cwd=tree, env=env, stdout=log,
                                stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(proc.pid, 0)  # this process's own peak (and its side processes')
        proc.returncode = os.waitstatus_to_exitcode(status)
    return time.perf_counter() - t, usage.ru_maxrss / 1024


def same_tables(run: Path, work: Path, revision: int) -> str:
    """"all N equal" or the tables that differ from the committed run's."""
    files = [*sorted((run / "calibrate" / f"rev{revision}").rglob("*.parquet")),
             *sorted((run / "posterior").glob("*.parquet"))]
    differ = [f.relative_to(run).as_posix() for f in files
              if not pd.read_parquet(f).equals(pd.read_parquet(work / f.relative_to(run)))]
    return f"all {len(files)} equal" if not differ else "DIFFERENT: " + ", ".join(differ)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline", required=True, help="the revision to compare with (a git worktree of it)")
    ap.add_argument("--run", type=Path, default=Path("sample_runs/hidden-effect"))
    ap.add_argument("--revision", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=2)
    a = ap.parse_args()
    here = Path(__file__).resolve().parents[1]
    run = a.run.resolve()
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp) / "baseline"
        subprocess.run(["git", "worktree", "add", "--detach", "-q", str(base), a.baseline], cwd=here, check=True)
        try:
            times: dict[str, list[float]] = {"baseline": [], "this tree": []}
            trees = [("baseline", base), ("this tree", here)]
            for rep in range(a.repeats):
                for name, tree in (trees if rep % 2 == 0 else trees[::-1]):
                    work = Path(tmp) / f"run-{rep}-{name.replace(' ', '-')}"
                    wall, peak = refit(tree, run, a.revision, work)
                    times[name].append(wall)
                    print(f"{name:10}  {wall:6.1f} s  peak {peak:6.0f} MB  "
                          f"{same_tables(run, work, a.revision)}", flush=True)
                    shutil.rmtree(work)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(base)], cwd=here, check=False)
    med = {k: statistics.median(v) for k, v in times.items()}
    print(f"medians: baseline {med['baseline']:.1f} s, this tree {med['this tree']:.1f} s; "
          f"this tree / baseline {med['this tree'] / med['baseline']:.3f}")


if __name__ == "__main__":
    main()

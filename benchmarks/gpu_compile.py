"""Compile the GPU engine's kernels to PTX for an H100/H200 (compute capability 9.0), with no GPU:
every kernel of four compositions that together use every contact law, from the same law functions
the CPU kernel runs. Needs the [gpu] extra (numba-cuda and CUDA's NVVM).

Where CUDA's assembler (``ptxas``) is on PATH it also assembles each kernel for sm_90 and prints its
registers a thread, its spills, and the occupancy they allow at the engine's 128 threads a block (the
share of a multiprocessor's 64 warps that can be resident: what hides a contact's memory latency): the
forces kernel's 152 registers are what the H200 reported for it (docs/performance.md), found here without
a GPU.

    NUMBA_ENABLE_CUDASIM=0 python benchmarks/gpu_compile.py [--registers [--max-registers=128,96,64]] \
        [--precision=mixed]

``--max-registers``: the force kernels assembled again under each cap, to see what it spills.
``--precision=mixed``: the kernels of heaps whose velocities, spins, forces, torques and contact histories
are float32 (calib_cli.dem.system.PRECISIONS).
"""
import importlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

os.environ["NUMBA_ENABLE_CUDASIM"] = "0"
# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np  # noqa: E402

from calib_cli.dem import gpu  # noqa: E402
from calib_cli.dem.materials import Interaction, Material  # noqa: E402
from calib_cli.dem.system import Particles, System, Walls  # noqa: E402

COMPOSITIONS = [  # (grains' values, walls' values): every law of every family at least once
    ({}, {}),
    ({"surface_energy": 0.5}, {"surface_energy": 0.5}),
    ({"surface_energy": 0.5, "rolling_spring": 1.0, "caps_pulloff": 1.0}, {"rolling_spring": 1.0, "caps_pulloff": 1.0}),
    ({"surface_tension": 0.072, "rolling_own_spin": 1.0, "friction_net_force": 1.0},
     {"rolling_own_spin": 1.0, "friction_net_force": 1.0}),
]
#: an sm_90 multiprocessor: registers, resident warps, resident blocks; a warp's registers are allocated in 256s
SM90 = {"regs": 65536, "warps": 64, "blocks": 32, "granule": 256}
BLOCK = 128


def system(grains: dict, walls: dict, precision: str = "double") -> System:
    rng = np.random.default_rng(0)
    pos = np.column_stack([rng.uniform(-3e-3, 3e-3, (8, 2)), 1.5e-3 + 3.1e-3 * np.arange(8)])
    it = Interaction(static_friction=0.5, rolling_friction=0.2, **grains)
    w = Interaction(static_friction=0.3, **walls)
    return System(Particles(pos, np.full(8, 1.5e-3)), material=Material(5e6, 0.25, 2600), pp=it, floor=w, cylinder=w,
                  walls=Walls(True, 6e-3, 0.05, 0.0), precision=precision)


def occupancy(regs: int, block: int = BLOCK) -> float:
    """The share of an sm_90 multiprocessor's warps resident at ``regs`` registers a thread."""
    warps = -(-block // 32)
    per_warp = -(-regs * 32 // SM90["granule"]) * SM90["granule"]
    blocks = min(SM90["regs"] // (per_warp * warps), SM90["blocks"], SM90["warps"] // warps)
    return blocks * warps / SM90["warps"]


def assemble(ptx: str, ptxas: str, max_registers: int = 0) -> str:
    """ptxas's resource line for one kernel: registers, spills (``max_registers``: ptxas's -maxrregcount,
    what ``CALIB_GPU_MAXREG`` asks of the GPU's linker). A PTX header newer than this ptxas reads (NVVM of a
    later CUDA than the assembler) is lowered to the assembler's own ISA version, which the kernels'
    instructions do not exceed; if they did, ptxas says so and the line says FAILED. A kernel that calls the
    device runtime (the persistent kernel's grid sync) is assembled as relocatable code (-c), as the GPU's
    linker then links it."""
    flags = ["-arch=sm_90", "-v"] + ([f"-maxrregcount={max_registers}"] if max_registers else [])
    with tempfile.TemporaryDirectory() as d:
        src = os.path.join(d, "k.ptx")
        for _ in range(3):
            open(src, "w").write(ptx)
            run = subprocess.run([ptxas, *flags, src, "-o", os.path.join(d, "k.cubin")], capture_output=True,
                                 text=True)
            own = re.search(r"current version is '([\d.]+)'", run.stderr)
            if own:
                ptx = re.sub(r"^\.version [\d.]+", f".version {own.group(1)}", ptx, count=1, flags=re.M)
            elif "Unresolved extern function" in run.stderr and "-c" not in flags:
                flags.append("-c")
            else:
                break
    if run.returncode:
        return f"FAILED ({run.stderr.strip().splitlines()[-1][:120]})"
    regs = int(re.search(r"Used (\d+) registers", run.stderr).group(1))
    spill = re.search(r"(\d+) bytes spill stores, (\d+) bytes spill loads", run.stderr)
    return (f"{regs:4d} registers, spills {spill.group(1)}/{spill.group(2)} B, "
            f"occupancy {100 * occupancy(regs):.1f} % at {BLOCK} threads a block")


def main() -> int:
    ptxas = shutil.which("ptxas") if "--registers" in sys.argv else None
    if "--registers" in sys.argv and not ptxas:
        print("--registers needs CUDA's ptxas on PATH")
        return 2
    caps = [int(v) for a in sys.argv if a.startswith("--max-registers=") for v in a.split("=", 1)[1].split(",")]
    precision = next((a.split("=", 1)[1] for a in sys.argv if a.startswith("--precision=")), "double")
    failed = 0
    for grains, walls in COMPOSITIONS:
        s = system(grains, walls, precision)
        t = time.perf_counter()
        try:
            ptx = gpu.compile_ptx(s.model.spec, [s], cc=(9, 0))
        except Exception as e:  # noqa: BLE001 - report and go on to the next composition
            failed += 1
            print(f"{s.model.spec}: FAILED {type(e).__name__}: {str(e).splitlines()[0][:200]}")
            continue
        ok = all(".target sm_90" in p for p in ptx.values())
        failed += not ok
        print(f"{s.model.spec}: {len(ptx)} kernels, sm_90 {'ok' if ok else 'MISSING'}, "
              f"{sum(map(len, ptx.values())) / 1e3:.0f} kB of PTX, {time.perf_counter() - t:.0f} s")
        for name, code in ptx.items() if ptxas else ():
            for cap in [0] + (caps if "forces" in name else []):
                line = assemble(code, ptxas, cap)
                failed += line.startswith("FAILED")
                print(f"  {name:16s} {line}" + (f" (capped at {cap})" if cap else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

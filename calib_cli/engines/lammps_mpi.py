"""Entry point of one MPI rank: `mpirun -np N python -m calib_cli.engines.lammps_mpi REQUEST.json OUT.npz`.

Every rank runs the same heap (LAMMPS splits the domain over MPI_COMM_WORLD); rank 0 writes the result.
"""

import json
import sys

import numpy as np

from ..dem.heap import HeapCondition, Numerics
from .lammps import _rank, run_heap_lammps


def main(req_path: str, out_path: str) -> None:
    req = json.load(open(req_path))
    res = run_heap_lammps(req["params"], HeapCondition(**req["condition"]), Numerics(**req["numerics"]), req["seed"])
    if _rank() == 0:
        p = res.system.particles
        scalars = {"status": res.status, "message": res.message, "t_settled": res.t_settled,
                   "t_lift_end": res.t_lift_end if np.isfinite(res.t_lift_end) else None, "t_end": res.t_end,
                   "wall_s": res.wall_s, "n_steps": res.system.n_steps, "dt": res.system.dt,
                   "energy": [list(e) for e in res.energy],
                   "angle_drift": res.angle_drift if np.isfinite(res.angle_drift) else None}
        np.savez(out_path + ".tmp.npz", x=p.pos, v=p.vel, omg=p.omg, rad=p.rad, scalars=json.dumps(scalars))
        import os

        os.replace(out_path + ".tmp.npz", out_path)


if __name__ == "__main__":
    main(*sys.argv[1:3])

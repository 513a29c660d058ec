"""Simulation campaigns: many heap runs, cached, resumable, on a local process pool.

Each run is identified by the hash of everything that determines its result (model,
parameters, condition, numerics, seed, the versions of its laws and kernel). Its artefacts live in
``RUN/simulate/runs/<hash>/`` and its ``result.json`` is written last, atomically: a
run with a result is never recomputed, and Ctrl-C loses nothing that finished. The
index ``RUN/simulate/results.parquet`` is rewritten (atomically) after every finished run, merged
with what is on disk under the run lock (:func:`append_index`).
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import functools
import os
import platform
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Mapping

import numpy as np
import pandas as pd

from . import __version__
from . import artifacts as art
from .dem import GPU_VERSION, KERNEL_VERSION
from .dem.laws import REGISTRY, ContactModel
from .dem.heap import (FLOOR_VARIABLES, LAWS, PARAMETERS, HeapCondition, HeapTest, Numerics, condition_dict,
                       heap_model, resume, run_heap, run_key)
from .dem.render import render_side_view
from .errors import CalibError
from .engines.clumps import SPHERES
from .imaging.measure import measure_image
from .profile import fullness

RESULTS = Path("simulate") / "results.parquet"
RUNS = Path("simulate") / "runs"
#: environment variable: other run directories (os.pathsep-separated) whose finished runs a
#: campaign copies instead of recomputing (docs/campaigns.md)
REUSE_ENV = "CALIB_REUSE"

def physics(model: ContactModel | None = None) -> dict[str, object]:
    """The physics a heap's cache key names: the kernel's version (integration, neighbour search, the
    force loop's assembly) and the name and version of each contact law the heap composes (``model``;
    every registered law without one), not the bytes of the source, so that a comment or a refactoring
    that keeps the arithmetic re-simulates nothing, and raising one law's version re-simulates exactly
    the heaps that used it."""
    laws = model.laws if model is not None else [law for family in REGISTRY.values() for law in family.values()]
    return {"kernel": KERNEL_VERSION, **{f"{law.family}={law.name}": law.version for law in laws}}


#: every law's version and the kernel's (docs; a heap's key takes only its own laws': :func:`heap_source`)
PHYSICS = physics()


def cache_source(physics: Mapping[str, object]) -> str:
    """The name of a physics version in cache keys and the results' `source` column: 77675d5eca62
    while the kernel and the laws named are at their first version (the last kernel source keyed by
    its bytes, whose heaps they compute bit for bit: the golden heaps of tests/test_heap.py), a hash
    of the versions after."""
    if str(physics.get("kernel")) == "1" and all(v == 1 for k, v in physics.items() if k != "kernel"):
        return "77675d5eca62"
    return art.hash_obj(dict(physics))[:12]


def heap_source(params: Mapping[str, float], condition: HeapCondition | None = None) -> str:
    """The physics version a heap of these parameters and condition runs (its laws' and the kernel's)."""
    return cache_source(physics(heap_model(params, condition)))


#: the version of the whole table (the kernel, every law): compare and diagnose name it in their settings, so
#: that any raised version re-runs them (the heaps it leaves unchanged come from the cache)
CACHE_SOURCE = cache_source(PHYSICS)
#: the second engines' own source (calib_cli/engines/: the LAMMPS parameter mapping, clumps), in their
#: heaps' keys beside CACHE_SOURCE: a changed mapping re-simulates instead of serving the old one's heaps
ENGINE_SOURCE = art.hash_obj({f.name: art.file_hash(f)
                              for f in sorted((Path(__file__).parent / "engines").glob("*.py"))})[:12]


@dataclass(frozen=True)
class Request:
    params: Mapping[str, float]
    condition: HeapCondition
    numerics: Numerics
    seed: int
    preset: str = ""
    design: str = ""  # the design stage this run belongs to ("pb", "bbd", ...), if any
    run_id: int = 0
    repeat: int = 0
    model: str = ""
    condition_id: str = ""
    engine: str = "builtin"  # builtin | lammps | gpu
    mpi: int = 1  # MPI ranks of a LAMMPS run (the summation order, hence the trajectory, depends on it)
    shapes: tuple[str, ...] = SPHERES  # grain shapes of a LAMMPS run (engines/clumps.py)

    @property
    def key(self) -> dict:
        k = run_key(self.params, self.condition, self.numerics, self.seed, self.model)
        k["source"] = self.source
        if self.engine != "builtin":  # keeps the built-in engine's existing cache keys
            k["engine"] = self.engine
            k["engine_source"] = f"gpu-{GPU_VERSION}" if self.engine == "gpu" else ENGINE_SOURCE
        if self.mpi > 1:
            k["mpi"] = self.mpi
        if tuple(self.shapes) != SPHERES:
            k["shapes"] = list(self.shapes)
        return k

    @property
    def source(self) -> str:
        """The physics version this heap runs (:func:`heap_source`)."""
        return heap_source(self.params, self.condition)

    @property
    def hash(self) -> str:
        return art.hash_obj(self.key)


def derive_seed(base: int, run_id: int, repeat: int) -> int:
    """Independent, reproducible seeds per (design run, repeat): two design runs at the same
    point (a PB design can repeat one) are separate replicates, not one cached run."""
    return int(np.random.SeedSequence([int(base), int(run_id), int(repeat)]).generate_state(1)[0] & 0x7FFFFFFF)


@functools.cache
def host() -> str:
    """What, besides the inputs in the run hash, the heap's last bits depend on: the instruction
    set numpy dispatches its ufunc loops on, numpy's and numba's versions.

    numpy sends float64 transcendental ufuncs (cbrt, power, ...) to AVX-512 loops (Intel's
    SVML) where the CPU has AVX-512 and to others elsewhere, which differ in the last place,
    and a heap amplifies any such difference until it settles differently (docs/performance.md,
    "Reproducibility": verified by switching numpy's AVX-512 loops off on one machine).
    """
    import numba

    return f"{platform.machine()} {simd_level()} numpy {np.__version__} numba {numba.__version__}"


def _numpy_cpu() -> tuple[list[str], dict]:
    """numpy's dispatch targets (lowest first) and the CPU features it found."""
    try:
        from numpy._core import _multiarray_umath as m
    except ImportError:  # numpy < 2
        from numpy.core import _multiarray_umath as m
    return list(m.__cpu_dispatch__), dict(m.__cpu_features__)


def numpy_dispatch_targets() -> list[str]:
    """The SIMD targets numpy can dispatch its ufunc loops on, lowest first (NPY_DISABLE_CPU_FEATURES
    takes names from this list)."""
    return _numpy_cpu()[0]


def simd_level() -> str:
    """The highest of numpy's dispatch targets this CPU (and NPY_DISABLE_CPU_FEATURES) enables,
    e.g. X86_V3 (AVX2) or AVX512_ICL; the baseline if none."""
    targets, cpu = _numpy_cpu()
    on = [t for t in targets if cpu.get(t)]
    return on[-1] if on else "baseline"


def _row(req: Request, res, img) -> dict:
    """The results row. The primary angle is the rendered side view's (``img``; None for a run that blew
    up), measured by the same code as the photographs (SPEC 5), falling back to the coordinate angle."""
    a = res.angle
    ok = res.status == "ok"
    s = res.system
    img_ok = ok and img is not None and img.status == "ok"
    primary = img.repose_angle if img_ok else a.angle
    return {
        "run_hash": req.hash, "design": req.design, "run_id": req.run_id, "repeat": req.repeat,
        "seed": req.seed, "preset": req.preset, "condition_id": req.condition_id, "model": req.model,
        "engine": req.engine, "mpi": req.mpi,
        # only on LAMMPS rows: the built-in kernel's rows (and the committed sample runs) keep their columns
        **({"shapes": ",".join(req.shapes)} if req.engine == "lammps" else {}),
        # only where the modulus is not the presets' reduced one (--shear-modulus), for the same reason
        **({"shear_modulus": req.numerics.shear_modulus}
           if req.numerics.shear_modulus != Numerics.shear_modulus else {}),
        **{k: float(v) for k, v in req.params.items()},
        **condition_dict(req.condition),  # the floor values only where given
        "status": res.status, "message": res.message,
        "repose_angle": primary if ok else np.nan,
        "angle_coords": a.angle if ok else np.nan,
        "angle_coords_sd": a.sd if ok else np.nan,
        "angle_image": img.repose_angle if img_ok else np.nan,
        "angle_image_left": img.angle_left if img_ok else np.nan,
        "angle_image_right": img.angle_right if img_ok else np.nan,
        "fullness": fullness(img.profile_s, img.profile_h) if img_ok else np.nan,
        "heap_height_mm": a.height * 1e3, "base_radius_mm": a.base_radius * 1e3,
        "angle_drift_deg_s": float(res.angle_drift),
        "n_particles": s.n, "n_steps": s.n_steps, "dt": s.dt, "t_end": res.t_end,
        "t_settled": res.t_settled, "t_lift_end": res.t_lift_end, "max_overlap": s.max_overlap,
        "wall_s": res.wall_s, "particle_steps_per_s": s.n * s.n_steps / max(res.wall_s, 1e-9),
        "kernel": KERNEL_VERSION, "source": req.source, "version": __version__, "host": host(),
    }


def execute(req: Request, run_dir: str, progress: Callable | None = None, force: bool = False) -> dict:
    """Run one request (or load its cached result, unless ``force``) and write its artefacts. A heap
    on the built-in or GPU engine goes on from its checkpoint, if a stopped run left one."""
    out = Path(run_dir) / RUNS / req.hash
    _restore(out)
    done = out / "result.json"
    if done.is_file() and not force:
        return art.read_json(done)
    ck = checkpoint_path(Path(run_dir), req, fresh=force)
    if req.engine == "lammps":
        from .engines.lammps import run_heap_lammps

        res = run_heap_lammps(req.params, req.condition, req.numerics, req.seed, progress=progress, mpi=req.mpi,
                              shapes=tuple(req.shapes))
    elif req.engine == "gpu":
        from .dem.gpu import run_heaps

        res = run_heaps([resume(HeapTest(req.params, req.condition, req.numerics, req.seed, progress), ck)],
                        checkpoints=[ck])[0]
    else:
        res = run_heap(req.params, req.condition, req.numerics, req.seed, progress=progress, checkpoint=ck)
    row = _store(req, res, Path(run_dir))
    ck.unlink(missing_ok=True)
    return row


def checkpoint_path(run_dir: Path, req: Request, fresh: bool = False) -> Path:
    """Where a stopped heap keeps its state (``RUN/simulate/runs/.<hash>.checkpoint.npz``); ``fresh``
    (``--force``) deletes it: the heap starts again from its fill."""
    ck = Path(run_dir) / RUNS / f".{req.hash}.checkpoint.npz"
    if fresh:
        ck.unlink(missing_ok=True)
    return ck


def _write_run(out: Path, req: Request, res) -> dict:
    """A finished heap's artefacts into ``out``; returns its results row (result.json, written last)."""
    p = res.system.particles
    state = pd.DataFrame({"x": p.pos[:, 0], "y": p.pos[:, 1], "z": p.pos[:, 2], "radius": p.rad,
                          "vx": p.vel[:, 0], "vy": p.vel[:, 1], "vz": p.vel[:, 2],
                          "wx": p.omg[:, 0], "wy": p.omg[:, 1], "wz": p.omg[:, 2]})
    # a blown-up run's grains may be anywhere (or NaN): it has no side view to render or measure
    view = render_side_view(p.pos, p.rad) if res.status != "unstable" else None
    # without the photographs' shape checks: a run's hash does not cover the measurement code, so a cached row
    # and a fresh one must agree; the coordinate path has its own (column, no_heap)
    row = _row(req, res, measure_image(view.image, limits=None) if view is not None else None)
    art.write_table(out / "state.parquet", state, {"stage": "simulate", "key": req.key, "version": __version__})
    art.write_table(out / "profile.parquet", pd.DataFrame({"r_m": res.angle.profile_r, "h_m": res.angle.profile_h}))
    art.write_table(out / "energy.parquet", pd.DataFrame(res.energy, columns=["t", "kinetic_energy", "rim_height"]))
    if view is not None:
        art.write_png(out / "side.png", view.image)
    art.write_vtp(out / "particles.vtp", p.pos, {"radius": p.rad, "velocity": p.vel, "angular_velocity": p.omg})
    art.write_json(out / "key.json", req.key)
    art.write_json(out / "result.json", row)  # last: marks the run complete
    return row


def _swap_in(tmp: Path, out: Path) -> None:
    """Make the complete run folder ``tmp`` the cached run ``out``. A run being recomputed (--force)
    stays whole and readable until its replacement is complete: the old folder steps aside to
    ``.<hash>.old`` only for the two renames (:func:`_restore` puts it back if a crash falls between)."""
    old = out.with_name(f".{out.name}.old")
    shutil.rmtree(old, ignore_errors=True)
    if out.exists():
        out.rename(old)
    tmp.rename(out)
    shutil.rmtree(old, ignore_errors=True)


def _restore(out: Path) -> None:
    """Put back a cached run a crash left stepped aside between :func:`_swap_in`'s two renames."""
    old = out.with_name(f".{out.name}.old")
    if not out.exists() and (old / "result.json").is_file():
        with contextlib.suppress(OSError):
            old.rename(out)


def _execute_in_worker(req: Request, run_dir: str, force: bool = False) -> dict:
    import numba

    numba.set_num_threads(1)  # one heap per core: the pool is the parallelism (results do not depend on it)
    return execute(req, run_dir, force=force)


def load_results(run_dir: Path) -> pd.DataFrame:
    path = Path(run_dir) / RESULTS
    if not path.is_file():
        return pd.DataFrame()
    try:
        return art.read_table(path, what="simulation results")
    except CalibError as e:  # the index is rebuilt from the heaps' folders: say how to get there
        raise CalibError(f"{e}; delete it and rerun: the index is rebuilt from the heaps kept in "
                         f"{Path(run_dir) / RUNS} (a heap whose folder is gone is simulated again)") from None


def current_sources(rows: pd.DataFrame) -> pd.Series:
    """The physics version each results row's heap would run now (its parameters' and floor's laws);
    "" where they are no longer valid parameters."""
    cols = tuple(c for c in (*PARAMETERS, *FLOOR_VARIABLES) if c in rows.columns)
    laws = cache_source(physics())  # the laws' versions now: the memo holds per state of the registry
    out = [_source_now(laws, cols, tuple(None if pd.isna(v) else v for v in vals))
           for vals in rows[list(cols)].itertuples(index=False, name=None)]
    return pd.Series(out, index=rows.index, dtype=object)


@functools.lru_cache(maxsize=65536)
def _source_now(laws: str, cols: tuple[str, ...], vals: tuple) -> str:
    """The physics version a parameter set runs today: worked out once per process (an index holds few
    distinct sets among many rows, and every stage that reads results asks for them again)."""
    given = {k: float(v) for k, v in zip(cols, vals) if v is not None}
    floor = {k: v for k, v in given.items() if k in FLOOR_VARIABLES}
    try:
        return heap_source({k: v for k, v in given.items() if k not in floor}, HeapCondition(**floor))
    except (CalibError, TypeError, ValueError):
        return ""


def current_results(run_dir: Path) -> pd.DataFrame:
    """The index rows an analysis may use: those of the physics their heaps run now (:func:`heap_source`),
    each run once.

    The index keeps rows of older kernel or law versions (their artefacts stay in the cache), but they
    are other simulations: averaging them with the current ones as if they were repeats shifted
    a whole calibration (found on a fresh clone whose committed index held older rows).
    """
    df = load_results(run_dir)
    if df.empty:
        return df
    if "source" in df.columns:
        df = df[df["source"] == current_sources(df)]
    if "run_hash" not in df.columns:  # not an index written by calib: nothing to de-duplicate by
        return df.reset_index(drop=True)
    keys = [k for k in ("run_hash", "design", "run_id", "repeat", "condition_id") if k in df.columns]
    return df.drop_duplicates(subset=keys, keep="last").reset_index(drop=True)


def row_moduli(rows: pd.DataFrame) -> pd.Series:
    """Each simulation row's shear modulus (rows at the presets' modulus do not carry the column)."""
    if "shear_modulus" in rows.columns:
        return rows["shear_modulus"].fillna(Numerics.shear_modulus)
    return pd.Series(Numerics.shear_modulus, index=rows.index)


def row_laws(rows: pd.DataFrame) -> list[dict[str, float]]:
    """Each simulation row's contact-law switches that are on (:data:`..dem.heap.LAWS`; off, 0,
    is every law's default, and rows that did not set one lack its column or hold NaN)."""
    on = [k for k in LAWS if k in rows.columns]
    return [{k: float(r[k]) for k in on if pd.notna(r[k]) and r[k] != 0} for _, r in rows[on].iterrows()] \
        if on else [{} for _ in range(len(rows))]


def heap_setups(rows: pd.DataFrame) -> list[str]:
    """The distinct (preset, shear modulus, contact laws switched on) of simulation rows, as
    'preset default at 5 MPa' or 'preset default at 5 MPa, rolling_spring 1'."""
    if rows.empty or "preset" not in rows.columns:
        return []
    return sorted({f"preset {p} at {m / 1e6:g} MPa" + "".join(f", {k} {v:g}" for k, v in sorted(law.items()))
                   for p, m, law in zip(rows["preset"], row_moduli(rows), row_laws(rows))})


def _save_index(run_dir: Path, rows: list[dict]) -> None:
    """One row per (run, design, run id, repeat, condition), the latest content in the place of
    the first: a rerun of finished runs leaves the index as it was, byte for byte, so the stages
    that read it stay up to date (moving rerun rows to the end changed its hash and re-ran them)."""
    keys = ("run_hash", "design", "run_id", "repeat", "condition_id")
    latest: dict[tuple, dict] = {}
    for r in rows:
        latest[tuple(str(r.get(k)) for k in keys)] = r  # an existing key keeps its place
    columns = list(dict.fromkeys(k for r in rows for k in r))  # as pd.DataFrame(rows) orders them
    art.write_table(Path(run_dir) / RESULTS, pd.DataFrame(list(latest.values()), columns=columns),
                    {"stage": "simulate", "version": __version__})


def append_index(run_dir: Path, rows: list[dict]) -> None:
    """Add finished runs' rows to RUN/simulate/results.parquet: merged with the index as it is on disk
    now, under the run lock. Each command used to rewrite it from the copy it read at its start, so
    two writers (or any row added meanwhile) lost rows."""
    if not rows:
        return
    with art.run_lock(run_dir, wait=True):
        previous = load_results(run_dir)
        _save_index(run_dir, (previous.to_dict("records") if len(previous) else []) + list(rows))


def reusable(run_hash: str) -> Path | None:
    """The folder of a finished run with this hash in a run directory named in $CALIB_REUSE, if any
    (asked only for runs the campaign's own directory lacks, so naming it there is harmless).

    The hash covers everything that determines the run (model, parameters, condition, numerics,
    seed, the versions of its laws and kernel), so that run is the one this campaign would compute, bit for bit."""
    for other in filter(None, os.environ.get(REUSE_ENV, "").split(os.pathsep)):
        src = Path(other) / RUNS / run_hash
        if (src / "result.json").is_file():
            return src
    return None


def _reuse(run_hash: str, run_dir: Path) -> bool:
    """Copy the :func:`reusable` run into this run directory; the index row then takes its labels
    (design, run id, repeat, condition) from the request. Copied to a staging name and renamed, so
    a copy cut short is never taken for a finished run."""
    src = reusable(run_hash)
    if src is None:
        return False
    dst = Path(run_dir) / RUNS / run_hash
    tmp = dst.with_name(f".{run_hash}.staging-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(src, tmp)
    shutil.rmtree(dst, ignore_errors=True)  # an unfinished run's leftovers
    tmp.rename(dst)
    return True


def run_campaign(requests: Iterable[Request], run_dir: Path, workers: int = 1,
                 on_done: Callable[[Request, dict], None] | None = None,
                 on_progress: Callable | None = None, dask: str | None = None,
                 reuse: bool = True, force: bool = False) -> pd.DataFrame:
    """Run every request (cached ones are loaded, not recomputed); return their rows.

    With ``reuse``, runs that the run directories in $CALIB_REUSE have finished are copied
    (:func:`reusable`). ``force`` (``--force``) recomputes every request, cached or not, and copies
    none; each cached run is replaced only once its new result is complete (:func:`_swap_in`).

    Executors: in-process (workers = 1), a local process pool (workers > 1), or a Dask cluster
    (``dask`` = a scheduler address, or "local" for a LocalCluster of ``workers`` processes).
    Every executor writes through :func:`execute` into the same cache, so results do not depend
    on where they ran; Dask workers must see the run directory (a shared filesystem).
    """
    requests = list(requests)
    run_dir = Path(run_dir)
    (run_dir / RUNS).mkdir(parents=True, exist_ok=True)
    rows: list[dict | None] = [None] * len(requests)

    def label(i: int, row: dict) -> dict:
        req = requests[i]
        rows[i] = {**row, "design": req.design, "run_id": req.run_id, "repeat": req.repeat,
                   "condition_id": req.condition_id}
        return rows[i]

    def finish(i: int, row: dict) -> None:
        append_index(run_dir, [label(i, row)])
        if on_done:
            on_done(requests[i], rows[i])

    todo, cached, twins = _plan(requests, run_dir, force, reuse)
    append_index(run_dir, [label(i, art.read_json(run_dir / RUNS / requests[i].hash / "result.json")) for i in cached])
    for i in cached:  # one write of the index for all of them
        if on_done:
            on_done(requests[i], rows[i])
    on_gpu = [i for i in todo if requests[i].engine == "gpu"]
    if on_gpu:  # together, in batches: not one heap per worker
        for i, row in _execute_on_gpu([requests[i] for i in on_gpu], on_gpu, run_dir, force):
            finish(i, row)
        todo = [i for i in todo if requests[i].engine != "gpu"]
    if dask and todo:
        from distributed import Client, LocalCluster, as_completed

        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None) if dask == "local" else None
        client = Client(cluster if cluster is not None else dask)
        try:
            futs = {client.submit(_execute_in_worker, requests[i], str(run_dir.resolve()), force, pure=False): i
                    for i in todo}
            try:
                for f in as_completed(list(futs)):
                    finish(futs[f], f.result())
            except BaseException:
                client.cancel(list(futs))
                raise
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    elif workers <= 1 or len(todo) <= 1:
        for i in todo:
            finish(i, execute(requests[i], str(run_dir), on_progress, force))
    else:
        import multiprocessing

        # spawn, not fork: numba's threading layer is not fork-safe once the parent has used it
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            futs = {pool.submit(_execute_in_worker, requests[i], str(run_dir), force): i for i in todo}
            try:
                for f in cf.as_completed(futs):
                    finish(futs[f], f.result())
            except BaseException:
                for f in futs:
                    f.cancel()
                raise
    for i in twins:  # computed once, above, under its first request's labels
        finish(i, art.read_json(run_dir / RUNS / requests[i].hash / "result.json"))
    return pd.DataFrame([r for r in rows if r is not None])


#: heaps a GPU batch holds at most: a step costs about the same from 1 to 256 `default` heaps on an H200
#: (docs/performance.md), and each finished batch is written to the cache, so a stop loses one
GPU_BATCH = 256


def _execute_on_gpu(reqs: list[Request], labels: list[int], run_dir: Path, force: bool = False):
    """Run requests on the GPU engine, :data:`GPU_BATCH` heaps at a time (calib_cli.dem.gpu), each from its
    checkpoint where a stopped run left one; yields (label, results row) as each batch's heaps are
    written, as :func:`execute` writes one."""
    from .dem.gpu import run_heaps

    for a in range(0, len(reqs), GPU_BATCH):
        part = reqs[a:a + GPU_BATCH]
        cks = [checkpoint_path(run_dir, r, fresh=force) for r in part]
        tests = [resume(HeapTest(r.params, r.condition, r.numerics, r.seed), ck) for r, ck in zip(part, cks)]
        for req, res, label, ck in zip(part, run_heaps(tests, checkpoints=cks), labels[a:a + GPU_BATCH], cks):
            yield label, _store(req, res, run_dir)
            ck.unlink(missing_ok=True)


def _store(req: Request, res, run_dir: Path) -> dict:
    """Write a finished heap's folder through a staging folder (a cached one is replaced only then)."""
    out = Path(run_dir) / RUNS / req.hash
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{req.hash}.staging-"))
    try:
        row = _write_run(tmp, req, res)
        _swap_in(tmp, out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return row


def _plan(requests: list[Request], run_dir: Path, force: bool, reuse: bool) -> tuple[list, list, list]:
    """Which requests to compute, which are cached, and which repeat an earlier request's hash (a design
    that lists one point twice): those are computed once, not by two workers into one folder."""
    todo, cached, twins, first = [], [], [], set()
    for i, req in enumerate(requests):
        done = run_dir / RUNS / req.hash / "result.json"
        if not force and (done.is_file() or (reuse and _reuse(req.hash, run_dir))):
            cached.append(i)
        elif req.hash in first:
            twins.append(i)
        else:
            first.add(req.hash)
            todo.append(i)
    return todo, cached, twins

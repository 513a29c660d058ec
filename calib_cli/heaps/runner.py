"""Simulation campaigns: many heap runs, cached, resumable, on a local process pool, a Dask cluster or
the GPU in batches.

A run's artefacts live in ``RUN/simulate/runs/<hash>/`` (:mod:`.keys`) and its ``result.json`` is
written last, atomically: a run with a result is never recomputed, and Ctrl-C loses nothing that
finished. Each finished run's row goes into the results index at once (:func:`.index.append_index`).
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Callable, Iterable

import numpy as np
import pandas as pd

from .. import __version__
from .. import artifacts as art
from ..errors import CalibError
from ..pool import spawned
from ..dem import KERNEL_VERSION
from ..dem.heap import HeapTest, Numerics, condition_dict, resume, run_heap
from ..dem.render import side_views
from ..imaging.measure import measure_image
from ..profile import fullness
from .index import append_index, load_results
from .keys import RUNS, Request, host

#: environment variable: other run directories (os.pathsep-separated) whose finished runs a
#: campaign copies instead of recomputing (docs/campaigns.md)
REUSE_ENV = "CALIB_REUSE"


def _views_means(imgs: list) -> dict:
    """The mean angle and fullness over the side views that measured a heap (``side_views`` of them): a
    surrogate learns a heap's mean from them with less of the scatter that which flanks one view caught
    adds (the lab's photographs stay one view a pile)."""
    ok = [m for m in imgs if m is not None and m.status == "ok"]
    return {"angle_views": float(np.mean([m.repose_angle for m in ok])) if ok else np.nan,
            "fullness_views": float(np.mean([fullness(m.profile_s, m.profile_h) for m in ok])) if ok else np.nan,
            "side_views": len(ok)}


def _row(req: Request, res, img, views: list | None = None) -> dict:
    """The results row. The primary angle is the rendered side view's (``img``; None for a run that blew
    up), measured by the same code as the photographs (SPEC 5), falling back to the coordinate angle;
    ``views`` (``img`` first) give the means over every side view."""
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
        **({"precision": req.numerics.precision} if req.numerics.precision != Numerics.precision else {}),
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
        **_views_means(views if ok and views else []),
        "heap_height_mm": a.height * 1e3, "base_radius_mm": a.base_radius * 1e3,
        "angle_drift_deg_s": float(res.angle_drift),
        "n_particles": s.n, "n_steps": s.n_steps, "dt": s.dt, "t_end": res.t_end,
        "t_settled": res.t_settled, "t_lift_end": res.t_lift_end, "max_overlap": s.max_overlap,
        "wall_s": res.wall_s, "particle_steps_per_s": s.n * s.n_steps / max(res.wall_s, 1e-9),
        "kernel": KERNEL_VERSION, "source": req.source, "version": __version__, "host": host(),
    }


def cached_result(run_dir: Path, run_hash: str) -> dict:
    """A finished heap's result.json, checked to be that heap's row: a file edited or written by hand (``{}``,
    a list) would enter the results index as a row of NaN, or stop the campaign with a traceback."""
    path = Path(run_dir) / RUNS / run_hash / "result.json"
    row = art.read_json(path)
    if not isinstance(row, dict) or row.get("run_hash") != run_hash or "status" not in row:
        raise CalibError(f"{path} is not the result of heap {run_hash} (a file calib did not write, or one "
                         f"edited): move {path.parent} aside to simulate the heap again")
    return row


def execute(req: Request, run_dir: str, progress: Callable | None = None, force: bool = False) -> dict:
    """Run one request (or load its cached result, unless ``force``) and write its artefacts. A heap
    on the built-in or GPU engine goes on from its checkpoint, if a stopped run left one."""
    out = Path(run_dir) / RUNS / req.hash
    _restore(out)
    done = out / "result.json"
    if done.is_file() and not force:
        return cached_result(Path(run_dir), req.hash)
    ck = checkpoint_path(Path(run_dir), req, fresh=force)
    if req.engine == "lammps":
        from ..engines.lammps import run_heap_lammps

        res = run_heap_lammps(req.params, req.condition, req.numerics, req.seed, progress=progress, mpi=req.mpi,
                              shapes=tuple(req.shapes))
    elif req.engine == "gpu":
        from ..dem.gpu import run_heaps

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
    views = side_views(p.pos, p.rad) if res.status != "unstable" else []
    # without the photographs' shape checks: a run's hash does not cover the measurement code, so a cached row
    # and a fresh one must agree; the coordinate path has its own (column, no_heap)
    imgs = [measure_image(v.image, limits=None) for v in views]
    row = _row(req, res, imgs[0] if imgs else None, imgs)
    view = views[0] if views else None
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
                 reuse: bool = True, force: bool = False, rows_suffice: bool = False) -> pd.DataFrame:
    """Run every request (cached ones are loaded, not recomputed); return their rows.

    With ``rows_suffice`` (a caller that reads only the heaps' rows, not their folders: the posterior's
    rounds, compare, diagnose) a heap whose row the run's results index holds is not simulated again
    when its folder is gone: a committed run keeps its rows, not its heaps' folders.

    With ``reuse``, runs that the run directories in $CALIB_REUSE have finished are copied
    (:func:`reusable`). ``force`` (``--force``) recomputes every request, cached or not, and copies
    none; each cached run is replaced only once its new result is complete (:func:`_swap_in`).

    Executors: in-process (workers = 1), a local process pool (workers > 1), or a Dask cluster
    (``dask`` = a scheduler address, or "local" for a LocalCluster of ``workers`` processes).
    Every executor writes through :func:`execute` into the same cache, so results do not depend
    on where they ran; Dask workers must see the run directory (a shared filesystem).
    """
    check_dask(dask)
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
    for i in cached:
        label(i, cached_result(run_dir, requests[i].hash))
    indexed = _indexed_rows(run_dir, [requests[i] for i in todo]) if rows_suffice and not force else {}
    for i in [i for i in todo + twins if requests[i].hash in indexed]:
        label(i, indexed[requests[i].hash])
    todo, twins = [i for i in todo if rows[i] is None], [i for i in twins if rows[i] is None]
    cached = [i for i in range(len(requests)) if rows[i] is not None]  # from their folders or the index
    append_index(run_dir, [rows[i] for i in cached])  # one write of the index for all of them
    for i in cached:
        if on_done:
            on_done(requests[i], rows[i])
    on_gpu = [i for i in todo if requests[i].engine == "gpu"]
    if on_gpu:  # together, in batches: not one heap per worker
        for i, row in _execute_on_gpu([requests[i] for i in on_gpu], on_gpu, run_dir, force):
            finish(i, row)
        todo = [i for i in todo if requests[i].engine != "gpu"]
    if dask and todo:
        _run_on_dask([(i, requests[i]) for i in todo], run_dir, dask, workers, force, finish)
    elif workers <= 1 or len(todo) <= 1:
        for i in todo:
            finish(i, execute(requests[i], str(run_dir), on_progress, force))
    else:
        _run_on_pool([(i, requests[i]) for i in todo], run_dir, workers, force, finish)
    for i in twins:  # computed once, above, under its first request's labels
        finish(i, cached_result(run_dir, requests[i].hash))
    return pd.DataFrame([r for r in rows if r is not None])


def _indexed_rows(run_dir: Path, requests: list[Request]) -> dict[str, dict]:
    """The results index's row of each request's heap it holds, without its labels (the request's are put
    on it): the row under the request's own labels where there is one (a heap recomputed under them with
    --force is rewritten there), else any row of that heap."""
    index = load_results(run_dir)
    if index.empty or "run_hash" not in index.columns or not requests:
        return {}
    labels = ["design", "run_id", "repeat", "condition_id"]
    hit = index[index["run_hash"].isin({r.hash for r in requests})]
    own = {(r.hash, r.design, r.run_id, r.repeat, r.condition_id) for r in requests}
    mine = [tuple(x) in own for x in hit[["run_hash", *labels]].itertuples(index=False)]
    hit = hit.assign(_own=mine).sort_values("_own", kind="stable").drop_duplicates("run_hash", keep="last")
    return {r["run_hash"]: {k: v for k, v in r.items() if k not in labels and k != "_own"}
            for r in hit.to_dict("records")}


def check_dask(dask: str | None) -> None:
    """Refuse a ``--dask`` that is neither "local" nor a scheduler address (``[protocol://]host:port``),
    before any heap runs."""
    if not dask or dask == "local":
        return
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, loc = parse_address(dask)
        if scheme != "inproc":
            parse_host_port(loc)
    except ValueError as e:
        raise CalibError(f"--dask {dask!r} is not a scheduler address ({e}): give tcp://HOST:PORT as `dask "
                         "scheduler` prints it, or local") from None


def _client(dask: str, cluster):
    """A client of the local ``cluster`` (closed where none comes of it, its own error raised) or of the
    scheduler at ``dask``."""
    from distributed import Client

    if cluster is not None:
        try:
            return Client(cluster)
        except BaseException:
            cluster.close()
            raise
    try:
        return Client(dask)
    except (OSError, TimeoutError) as e:
        raise CalibError(f"no Dask scheduler answered at {dask} ({e}): start one (`dask scheduler`) and its "
                         "workers where they see the run directory, or use --dask local") from None
    except Exception as e:  # another service there (an SSH banner read as a frame length: EiB asked for)
        said = str(e).splitlines()[0][:120] if str(e) else ""
        raise CalibError(f"{dask} did not answer as a Dask scheduler ({type(e).__name__}"
                         f"{': ' + said if said else ''}): is it the address `dask scheduler` printed?") from None


def _run_on_dask(todo: list[tuple[int, Request]], run_dir: Path, dask: str, workers: int, force: bool,
                 finish: Callable[[int, dict], None]) -> None:
    """Run (label, request) pairs on a Dask cluster (``dask``: a scheduler's address, or "local" for a
    LocalCluster of ``workers`` processes), calling ``finish(label, row)`` as each heap is done."""
    from distributed import LocalCluster, as_completed

    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           dashboard_address=None) if dask == "local" else None
    client = _client(dask, cluster)
    try:
        futs = {client.submit(_execute_in_worker, req, str(run_dir.resolve()), force, pure=False): i
                for i, req in todo}
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


def _run_on_pool(todo: list[tuple[int, Request]], run_dir: Path, workers: int, force: bool,
                 finish: Callable[[int, dict], None]) -> None:
    """Run (label, request) pairs on a local pool of ``workers`` processes, calling ``finish(label, row)``
    as each heap is done. A stop (Ctrl-C, an error) ends the workers at once: the heaps in flight are lost,
    as promised, and no queued one starts (a worker that caught Ctrl-C itself took the next queued heap, and
    the pool's exit waited for it)."""
    from concurrent.futures.process import BrokenProcessPool

    with spawned(workers) as pool:
        futs = {pool.submit(_execute_in_worker, req, str(run_dir), force): i for i, req in todo}
        try:
            for f in cf.as_completed(futs):
                finish(futs[f], f.result())
        except BrokenProcessPool:  # a worker killed from outside (the out-of-memory killer): the machine's, not a bug
            raise CalibError("a worker process died while simulating heaps (killed from outside: out of memory?); "
                             "the heaps it finished are kept, and the same command goes on from them (fewer "
                             "--workers use less memory)") from None


#: heaps a GPU batch holds at most: a step costs about the same from 1 to 256 `default` heaps on an H200
#: (docs/performance.md), and each finished batch is written to the cache, so a stop loses one
GPU_BATCH = 256


def _execute_on_gpu(reqs: list[Request], labels: list[int], run_dir: Path, force: bool = False):
    """Run requests on the GPU engine, :data:`GPU_BATCH` heaps at a time (calib_cli.dem.gpu), each from its
    checkpoint where a stopped run left one; yields (label, results row) as each batch's heaps are
    written, as :func:`execute` writes one."""
    from ..dem.gpu import run_heaps

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

"""The one module that reads and writes the run directory.

Every artefact is a Parquet file whose schema metadata carries its provenance
(``calib.provenance``: stage, command line, package version, input hashes, settings
hash, fingerprint). Writes are atomic: a stage writes everything into a staging
folder and only then renames each file into place, and its lock file
(``<stage>.lock.json``, in the spirit of DVC's ``dvc.lock``: the stage's fingerprint
and the hash of every output) is published last, by one rename. A stage whose fingerprint and
outputs are unchanged is skipped; an error before the commit leaves the run directory as it was,
and readers (:func:`read_table`) refuse an output whose hash no lock records, so a crash between
the renames cannot hand them a mix of two runs (:meth:`Stage._publish`).
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import hashlib
import json
import os
import shlex
import shutil
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from . import __version__
from .errors import CalibError, reason

PROVENANCE_KEY = b"calib.provenance"
LOCK_SUFFIX = ".lock.json"
#: ``.<stage>.pending.json``: the lock a commit will publish, written before its first rename and renamed
#: onto ``<stage>.lock.json`` after the last; while it exists the stage's commit is unfinished
PENDING_SUFFIX = ".pending.json"


# ---------------------------------------------------------------- hashing
def _canonical(obj: Any) -> Any:
    if isinstance(obj, Mapping):
        return {str(k): _canonical(v) for k, v in sorted(obj.items(), key=lambda kv: str(kv[0]))}
    if isinstance(obj, (list, tuple)):
        return [_canonical(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        return float(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, Path):
        return str(obj)
    return obj


def hash_obj(obj: Any) -> str:
    """Stable short hash of a JSON-able object (settings, parameters)."""
    data = json.dumps(_canonical(obj), sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(data.encode()).hexdigest()[:16]


def file_hash(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()[:16]


def frame_hash(df: pd.DataFrame) -> str:
    """Content hash of a table: its column names, dtypes and values (not its index)."""
    h = hashlib.sha256(json.dumps([[str(c), str(t)] for c, t in df.dtypes.items()]).encode())
    h.update(pd.util.hash_pandas_object(df, index=False).to_numpy().tobytes())
    return h.hexdigest()[:16]


@dataclass(frozen=True, eq=False)
class Rows:
    """A stage input that is part of a table other stages append to (RUN/simulate/results.parquet):
    the rows the stage read, locked by their content. Locking the whole file made every analysis
    stale as soon as a later stage's heaps were added, so a whole chain rerun redid them all."""

    path: Path
    frame: pd.DataFrame


def _input_hash(p: Path | Rows | None) -> str | None:
    if p is None:
        return None
    return frame_hash(p.frame) if isinstance(p, Rows) else file_hash(Path(p))


def _input_path(p: Path | Rows | None) -> str | None:
    if isinstance(p, Rows):
        return f"{p.path} ({len(p.frame)} rows read)"
    return str(p) if p is not None else None


def command_line() -> str:
    argv = list(sys.argv)
    if argv:
        argv[0] = Path(argv[0]).name
    return shlex.join(argv)


# ---------------------------------------------------------------- atomic primitives
def _usual_mode(fd: int) -> None:
    """A temporary file is made 0600; the file it becomes gets what any new file gets (0644 under the usual
    umask), so that a run directory can be shared and read by others like one written by hand."""
    mask = os.umask(0)
    os.umask(mask)
    os.fchmod(fd, 0o666 & ~mask)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    _usual_mode(fd)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _write_parquet(path: Path, df: pd.DataFrame, provenance: Mapping | None) -> None:
    table = pa.Table.from_pandas(df.reset_index(drop=True), preserve_index=False)
    meta = dict(table.schema.metadata or {})
    if provenance is not None:
        meta[PROVENANCE_KEY] = json.dumps(_canonical(dict(provenance)), default=str).encode()
    table = table.replace_schema_metadata(meta)
    pq.write_table(table, path)


def write_table(path: Path, df: pd.DataFrame, provenance: Mapping | None = None) -> None:
    """Write one Parquet artefact atomically (temporary file, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    _usual_mode(fd)
    os.close(fd)
    try:
        _write_parquet(Path(tmp), df, provenance)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _locks_listing(path: Path) -> tuple[list[tuple[str, str]], list[str]]:
    """(stage, hash) of each committed lock that lists ``path`` as an output, and the stages whose
    unfinished commit (a pending lock) lists it; a lock lists its outputs relative to its folder,
    the file's own or the one above."""
    committed, pending = [], []
    for folder in (path.parent, path.parent.parent):
        rel = path.relative_to(folder).as_posix()
        for lock in folder.glob(f"*{LOCK_SUFFIX}"):
            d = _read_lock_file(lock)
            if rel in d.get("outputs", {}):
                committed.append((str(d.get("stage", lock.name)), d["outputs"][rel]))
        for lock in folder.glob(f".*{PENDING_SUFFIX}"):
            d = _read_lock_file(lock)
            if rel in d.get("outputs", {}):
                pending.append(str(d.get("stage", lock.name)))
    return committed, pending


def check_not_pending(folder: Path, what: str) -> None:
    """Refuse a folder an unfinished commit is writing into (a pending lock there: another command at work, or
    one killed between its renames, which left files of two runs side by side), for readers of files no
    Parquet check covers (photographs, a conditions CSV)."""
    locks = {p: _read_lock_file(p) for p in Path(folder).glob(f".*{PENDING_SUFFIX}")}
    stages = sorted({command_of(str(d.get("stage", p.name))) for p, d in locks.items() if d})
    if stages:
        raise CalibError(f"{what} {folder} is being written, or its write was interrupted: rerun the command that "
                         f"writes it ({', '.join(stages)}) once no other command is writing there")


def _read_lock_file(path: Path) -> dict:
    try:
        d = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return d if isinstance(d, dict) and isinstance(d.get("outputs", {}), dict) else {}


#: the command that writes each stage (a lock names its stage ``group.name``; a user knows the commands)
STAGE_COMMANDS = {"measure": "calib measure-angle", "pb.design": "calib pb design", "pb.analyze": "calib pb analyze",
                  "ascent.design": "calib ascent design", "ascent.analyze": "calib ascent analyze",
                  "bbd.design": "calib bbd design", "bbd.analyze": "calib bbd analyze", "surrogate": "calib fit-surrogate",
                  "invert": "calib invert", "posterior": "calib calibrate-posterior or calib calibrate",
                  "calibrate": "calib calibrate", "compare": "calib compare", "diagnose": "calib diagnose",
                  "suggest": "calib suggest-conditions"}


def command_of(stage: str) -> str:
    """The command that writes stage ``group.name`` (the stage's own name where none is known)."""
    return STAGE_COMMANDS.get(stage) or STAGE_COMMANDS.get(stage.split(".")[0]) or stage


def check_committed(path: Path, what: str = "artefact") -> None:
    """Refuse a stage output that no committed lock vouches for: a file a lock (or an unfinished
    commit) lists must have the hash some committed lock records. A commit cut short between its
    renames leaves files of two runs side by side; this is what keeps a reader from mixing them.
    Files no lock lists (inputs, the simulation index, tables written by hand) are not checked."""
    path = Path(path)
    committed, pending = _locks_listing(path)
    if not committed and not pending:
        return
    if any(h == file_hash(path) for _, h in committed):
        return
    stages = sorted({command_of(s) for s, _ in committed} | {command_of(s) for s in pending})
    if pending:
        raise CalibError(f"{what} {path} is being written, or its write was interrupted: rerun the command that "
                         f"writes it ({', '.join(stages)}) once no other command is writing the run")
    raise CalibError(f"{what} {path} is not the output its stage's lock records (the file was changed by hand, or "
                     f"a write was interrupted): rerun the command that writes it ({', '.join(stages)}) with --force")


def read_table(path: Path, columns: Sequence[str] | None = None, what: str = "artefact") -> pd.DataFrame:
    """A Parquet artefact, checked against its stage's lock (:func:`check_committed`) where one lists it."""
    path = Path(path)
    if not path.is_file():
        raise CalibError(f"{what} not found: {path}")
    check_committed(path, what)
    try:
        df = pq.read_table(path).to_pandas()
    except Exception as e:  # pyarrow raises several types for corrupt files
        hint = ": a .csv is not one; give the .parquet a stage wrote" if path.suffix.lower() in (".csv", ".txt") else ""
        raise CalibError(f"{what} {path} is not a readable Parquet file ({type(e).__name__}){hint}") from None
    if columns:
        missing = [c for c in columns if c not in df.columns]
        if missing:
            raise CalibError(f"{what} {path} lacks column(s) {', '.join(missing)}")
    return df


def read_provenance(path: Path) -> dict:
    try:
        meta = pq.read_schema(path).metadata or {}
    except Exception:
        raise CalibError(f"{path} is not a readable Parquet file") from None
    raw = meta.get(PROVENANCE_KEY)
    try:
        out = json.loads(raw) if raw else {}
    except ValueError:
        out = None
    if not isinstance(out, dict):  # a file calib did not write, or one edited: its provenance is unreadable
        raise CalibError(f"{path} holds provenance that is not calib's (not a JSON table): rerun the command that "
                         "writes it, or move the file aside")
    return out


#: response columns that hold a repose angle (deg)
ANGLES = ("repose_angle", "angle_coords", "angle_image")


def _copies(out: pd.DataFrame, path: Path, response: str, warn: Optional[Callable[[str], None]]) -> None:
    """Rows that repeat an earlier row in every column. Where every row has a copy the table was pasted
    twice (or more): an error, as each copy would count as a run (more residual dof; the paper's Table 7
    doubled reads a predicted R2 of 0.96 for 0.79). Some copies are warned of only: repeated centre points
    agree to the digits a paper prints (whole degrees) or an engine that gives one answer per input,
    and they are runs of the design. A response of one value everywhere is left to the fit's own message."""
    dup = out.duplicated(keep=False).to_numpy()
    if not dup.any() or out[response].nunique() == 1:
        return
    copies = np.flatnonzero(out.duplicated(keep="first").to_numpy())
    i = int(copies[0])
    j = int(np.flatnonzero((out.iloc[:i] == out.iloc[i]).all(axis=1).to_numpy())[0])
    said = f"responses file {path}: row {i + 1} repeats row {j + 1} in every column"
    if dup.all():
        raise CalibError(f"{said}, and every other row repeats one too (the table pasted twice?): give each run "
                         "once; a copy would be counted as a run of its own")
    if warn is not None:
        more = f", and {len(copies) - 1} more row(s) repeat others" if len(copies) > 1 else ""
        warn(f"[yellow]warning:[/] {said}{more}: each is counted as a run of its own (repeats alike to the "
             f"digits given, or rows pasted twice?)")


def read_responses(path: Path, factors: Sequence[str], response: str,
                   optional: Sequence[str] = (), warn: Optional[Callable[[str], None]] = None) -> pd.DataFrame:
    """A responses table from another engine or a paper: CSV or Parquet.

    Factor columns in natural units plus the response column; every value numeric
    and finite, no rows copies of others (one is ``warn``-ed of).
    """
    path = Path(path)
    if not path.is_file():
        raise CalibError(f"responses file not found: {path}")
    suffix = path.suffix.lower()
    try:
        if suffix in (".parquet", ".pq"):
            df = pq.read_table(path).to_pandas()
        elif suffix in (".csv", ".txt", ".tsv"):
            df = pd.read_csv(path, sep=None, engine="python", comment="#")
        else:
            raise CalibError(f"responses file {path} must be .csv or .parquet")
    except CalibError:
        raise
    except Exception as e:
        raise CalibError(f"responses file {path} could not be read ({reason(e)})") from None
    df.columns = [str(c).strip() for c in df.columns]
    need = list(factors) + [response]
    missing = [c for c in need if c not in df.columns]
    if missing:
        raise CalibError(
            f"responses file {path} lacks column(s) {', '.join(missing)} (has: {', '.join(map(str, df.columns))})"
        )
    need += [c for c in optional if c in df.columns]
    out = df[need].copy()
    for c in need:
        vals = pd.to_numeric(out[c], errors="coerce")
        bad = ~np.isfinite(vals.to_numpy(dtype=float))
        if bad.any():
            rows = ", ".join(str(i + 1) for i in np.flatnonzero(bad)[:5])
            raise CalibError(f"responses file {path}: column {c!r} has missing or non-numeric values (row {rows})")
        out[c] = vals.astype(float)
    if len(out) == 0:
        raise CalibError(f"responses file {path} has no rows")
    _copies(out, path, response, warn)
    from .parameters import QUANTITIES, check

    for c in (c for c in factors if c in QUANTITIES):  # a factor's value as --set would take it
        for i, v in enumerate(out[c]):
            check(c, v, f"responses file {path}, row {i + 1}")
    if response in ANGLES:  # a repose angle outside (0, 90) deg is a typo or another quantity's column
        off = np.flatnonzero(~((out[response] > 0) & (out[response] < 90)).to_numpy())
        if len(off):
            rows = ", ".join(str(i + 1) for i in off[:5])
            raise CalibError(f"responses file {path}: {response} must lie in (0, 90) deg (row {rows}: "
                             f"{out[response].iloc[off[0]]:g})")
    return out


def write_json(path: Path, obj: Mapping) -> None:
    atomic_write_bytes(path, json.dumps(_canonical(dict(obj)), indent=2, default=str).encode())


def read_json(path: Path, what: str = "artefact") -> dict:
    """A JSON file; a stage output is checked against its stage's lock first, as :func:`read_table` does."""
    path = Path(path)
    if path.is_file():
        check_committed(path, what)
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        raise CalibError(f"{path} is missing or not valid JSON") from None


def png_bytes(image: np.ndarray) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise CalibError("could not encode an image as PNG")
    return buf.tobytes()


def write_png(path: Path, image: np.ndarray) -> None:
    atomic_write_bytes(path, png_bytes(image))


def write_vtp(path: Path, points: np.ndarray, point_data: Mapping[str, np.ndarray]) -> None:
    """Particles as VTK XML PolyData (ASCII), for ParaView: points plus per-point arrays."""
    pts = np.asarray(points, dtype=float)
    n = len(pts)

    def arr(name, a):
        a = np.asarray(a, dtype=float)
        comps = 1 if a.ndim == 1 else a.shape[1]
        body = " ".join(f"{v:.9g}" for v in a.ravel())
        nm = f' Name="{name}"' if name else ""
        return f'<DataArray type="Float64"{nm} NumberOfComponents="{comps}" format="ascii">{body}</DataArray>'

    pd_xml = "".join(arr(k, v) for k, v in point_data.items())
    verts = " ".join(str(i) for i in range(n))
    offs = " ".join(str(i + 1) for i in range(n))
    xml = ('<?xml version="1.0"?>\n<VTKFile type="PolyData" version="0.1" byte_order="LittleEndian">'
           f'<PolyData><Piece NumberOfPoints="{n}" NumberOfVerts="{n}" NumberOfLines="0" NumberOfStrips="0" '
           f'NumberOfPolys="0"><PointData Scalars="radius">{pd_xml}</PointData><Points>{arr("", pts)}</Points>'
           f'<Verts><DataArray type="Int64" Name="connectivity" format="ascii">{verts}</DataArray>'
           f'<DataArray type="Int64" Name="offsets" format="ascii">{offs}</DataArray></Verts>'
           '</Piece></PolyData></VTKFile>\n')
    atomic_write_bytes(path, xml.encode())


# ---------------------------------------------------------------- one writer per run directory
RUN_LOCK = ".lock"
#: the run directories this process holds (resolved path -> [file descriptor, depth]): the lock is
#: re-entrant, so a stage that calls another (invert --validate simulates) does not lock itself out
_HELD: dict[Path, list] = {}


def _holder(fd: int) -> str:
    with contextlib.suppress(OSError):
        text = os.pread(fd, 4096, 0).decode(errors="replace").strip()
        if text:
            return text
    return "a process that has not written its name yet"


@contextlib.contextmanager
def run_lock(run: Path, wait: bool = False):
    """Hold ``RUN/.lock`` (an OS lock, ``fcntl.flock``: released by the kernel when the holder exits,
    however it exits) for as long as the block runs. Two commands writing one run directory each
    rewrote the shared tables (results.parquet) from their own copy and lost the other's rows, so a
    second writer fails at once with a one-line error naming the holder (``wait``: blocks instead,
    for the short update of the simulation index). The file holds the holder's pid and command line."""
    run = Path(run)
    key = run.resolve()
    if key in _HELD:
        _HELD[key][1] += 1
        try:
            yield
        finally:
            _HELD[key][1] -= 1
        return
    created = not run.exists()
    # the folders mkdir makes above the run too: a failed first command leaves none of them behind
    made = [d for d in (run, *run.parents) if not d.exists()]
    try:
        run.mkdir(parents=True, exist_ok=True)
        fd = os.open(run / RUN_LOCK, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as e:
        if e.errno not in (errno.EACCES, errno.EPERM, errno.EROFS) or not run.is_dir():
            raise CalibError(f"cannot use {run} as a run directory: {e.strerror or e}") from None
        yield  # a read-only run directory (a committed sample run): nobody can write it either
        return
    fd = _acquire(fd, run, wait)  # closes its descriptor when it fails
    _HELD[key] = [fd, 1]
    try:  # from here a Ctrl-C or a full disk releases the lock too (a notebook's process lives on)
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()}: {command_line()}\n".encode(), 0)
        if not wait:  # a command's lock, not a library call's short index update (which may run beside its own stagings)
            sweep_leftovers(run)
        yield
    except BaseException:
        # nothing written: leave no run dir (a process waiting on this lock file finds it unlinked and
        # opens the new one: _acquire)
        if created and [p.name for p in run.iterdir()] == [RUN_LOCK]:
            with contextlib.suppress(OSError):
                (run / RUN_LOCK).unlink()
                for d in made:  # the run, then each parent it needed, while they are empty
                    d.rmdir()
        raise
    finally:
        del _HELD[key]
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)
        os.close(fd)  # closing the last descriptor releases the lock


def check_free(run: Path) -> None:
    """Refuse at once a run directory another calib command holds, with :func:`run_lock`'s one line: a command
    that plans before it writes (simulate-heap) printed its plan and progress bars first."""
    if Path(run).is_dir():
        with run_lock(run):
            pass


#: what a writer killed mid-write leaves: a stage's or a heap's staging folder, an atomic write's temporary file
LEFTOVERS = (".*.staging-*", ".*.tmp")


def sweep_leftovers(run: Path, depth: int = 2) -> int:
    """Delete the :data:`LEFTOVERS` in ``run`` and its folders down to ``depth`` (RUN/simulate/runs is
    2); returns how many. Only with the run lock newly taken: every writer is then gone, so what is
    staged belongs to a dead one. Nothing reads these names, so this only frees the space."""
    level, n = [Path(run)], 0
    for d in range(depth + 1):
        for folder in level:
            for pattern in LEFTOVERS:
                for p in folder.glob(pattern):
                    with contextlib.suppress(OSError):
                        shutil.rmtree(p) if p.is_dir() else p.unlink()
                        n += 1
        level = [c for f in level for c in _subfolders(f)] if d < depth else []
    return n


def _subfolders(folder: Path) -> list[Path]:
    """The folders a sweep goes on into: not hidden ones, nor one with a lock of its own (a lab folder synth-lab
    writes under its own lock: its leftovers are swept when that lock is taken)."""
    with contextlib.suppress(OSError):
        return [c for c in folder.iterdir() if c.is_dir() and not c.name.startswith(".")
                and not (c / RUN_LOCK).exists()]
    return []


def _acquire(fd: int, run: Path, wait: bool) -> int:
    """Lock ``fd`` (the run's lock file); returns the descriptor that holds the lock. A lock file that
    was unlinked while this process waited on it (the holder's command failed and removed its new run
    directory) locks nothing: the lock is taken again on the file now at the path."""
    import fcntl

    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise CalibError(f"run directory {run} is in use by another calib command ({holder}): one command "
                             "writes a run directory at a time; run this one when it has finished") from None
        try:
            if os.fstat(fd).st_ino == os.stat(run / RUN_LOCK).st_ino:
                return fd
        except FileNotFoundError:
            pass
        os.close(fd)
        run.mkdir(parents=True, exist_ok=True)
        fd = os.open(run / RUN_LOCK, os.O_RDWR | os.O_CREAT, 0o644)


# ---------------------------------------------------------------- stages
@dataclass
class Stage:
    """One run of one stage: declared inputs, settings, outputs; skip if unchanged.

    Usage::

        st = Stage(run_dir, "pb", "analyze", inputs={"design": p}, settings=cfg)
        if st.up_to_date() and not force: ...skip...
        with st.commit() as out:           # nothing reaches the run dir on error
            out.table("effects.parquet", df)
            out.figure("surface.png", fig)
    """

    run_dir: Path
    group: str
    name: str
    inputs: Mapping[str, Path | Rows | None] = field(default_factory=dict)
    settings: Mapping[str, Any] = field(default_factory=dict)
    extra: Mapping[str, Any] = field(default_factory=dict)
    #: the version of the code that computes the stage's outputs (raised when a change moves them), so
    #: that a lock written by older code is not up to date; 1 is left out of the fingerprint, which keeps
    #: the locks written before stages had versions
    code: int = 1

    def __post_init__(self) -> None:
        self.run_dir = Path(self.run_dir)
        self.input_hashes = {k: _input_hash(p) for k, p in self.inputs.items()}
        self.settings_hash = hash_obj(self.settings)
        self.fingerprint = hash_obj(
            {"stage": f"{self.group}.{self.name}", "version": __version__, "inputs": self.input_hashes,
             "settings": self.settings_hash, "extra": self.extra, **({"code": self.code} if self.code != 1 else {})}
        )

    @property
    def dir(self) -> Path:
        return self.run_dir / self.group

    @property
    def lock_path(self) -> Path:
        return self.dir / f"{self.name}{LOCK_SUFFIX}"

    def read_lock(self) -> dict | None:
        """The stage's lock, or None where it is missing or not a lock (not JSON, or JSON of another shape:
        the stage is then out of date and recomputes, as for a missing lock)."""
        return _read_lock_file(self.lock_path) or None

    @property
    def pending_path(self) -> Path:
        return self.dir / f".{self.name}{PENDING_SUFFIX}"

    def up_to_date(self) -> bool:
        lock = self.read_lock()
        if not lock or lock.get("fingerprint") != self.fingerprint or self.pending_path.exists():
            return False
        for rel, h in lock.get("outputs", {}).items():
            p = self.dir / rel
            if not p.is_file() or file_hash(p) != h:
                return False
        return True

    def provenance(self) -> dict:
        return {
            "stage": f"{self.group}.{self.name}",
            "command": command_line(),
            "version": __version__,
            "inputs": {k: {"path": _input_path(p), "hash": self.input_hashes[k]} for k, p in self.inputs.items()},
            "settings_hash": self.settings_hash,
            "fingerprint": self.fingerprint,
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            **({"extra": dict(self.extra)} if self.extra else {}),
        }

    @contextlib.contextmanager
    def commit(self):
        self.run_dir.mkdir(parents=True, exist_ok=True)
        _check_folder(self.dir, self.run_dir)
        self.dir.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(dir=self.dir, prefix=f".{self.name}.staging-"))
        writer = _StagingWriter(staging, self.provenance())
        try:
            yield writer
        except BaseException:
            shutil.rmtree(staging, ignore_errors=True)
            raise
        try:
            self._publish(staging, writer.written)
        finally:
            shutil.rmtree(staging, ignore_errors=True)

    def _publish(self, staging: Path, written: list[str]) -> None:
        """Move the staged outputs into place, all or nothing as readers see it: the new lock goes first
        to a pending name, the outputs are renamed one by one, and only then is the pending lock renamed
        onto the stage's lock (atomic). Until that rename the old lock still records the old outputs'
        hashes, so a crash in between leaves every file either the previous one (its hash matches) or
        refused by :func:`check_committed` (it matches no committed lock). The stale outputs (the old lock's,
        not written now) go before that rename: once the new lock stands no lock lists them, so one left by a
        kill after it would pass for a committed output."""
        old = (self.read_lock() or {}).get("outputs", {})
        for rel in [*written, *(r for r in set(old) - set(written) if _inside(self.dir, r))]:
            _check_file(self.dir / rel, self.dir)  # before anything moves: a folder there would stop it half-way
        hashes = {rel: file_hash(staging / rel) for rel in written}
        lock = {"stage": f"{self.group}.{self.name}", "fingerprint": self.fingerprint,
                "version": __version__, "code": self.code, "command": command_line(),
                "inputs": self.input_hashes, "settings_hash": self.settings_hash,
                "outputs": hashes}
        atomic_write_bytes(self.pending_path, json.dumps(lock, indent=2).encode())
        for rel in written:
            dst = self.dir / rel
            dst.parent.mkdir(parents=True, exist_ok=True)
            os.replace(staging / rel, dst)
        for rel in set(old) - set(hashes):
            if not _inside(self.dir, rel):  # a lock edited by hand names ../settings.toml: not the stage's to delete
                continue
            # gone already is fine; one that cannot be deleted stops the commit before the new lock stands (a
            # file left that no lock lists would pass for a committed output)
            with contextlib.suppress(FileNotFoundError):
                (self.dir / rel).unlink()
        os.replace(self.pending_path, self.lock_path)


def _check_folder(folder: Path, top: Path) -> None:
    """Refuse, in one line, a file where ``folder`` or a folder between it and ``top`` should be."""
    for p in [folder, *folder.parents]:
        if p == top or top not in p.parents:
            return
        if p.exists() and not p.is_dir():
            raise CalibError(f"{p} is a file where calib keeps a folder of outputs: move it aside and run again")


def _check_file(path: Path, top: Path) -> None:
    """Refuse, in one line, a folder where the output ``path`` goes (or a file where a folder above it does)."""
    if path.is_dir():
        raise CalibError(f"{path} is a folder where calib writes a file: move it aside and run again")
    _check_folder(path.parent, top)


def _inside(folder: Path, rel: str) -> bool:
    """Whether ``rel`` (an output a lock lists) names a file within ``folder``, not beside or above it."""
    p = Path(rel)
    return not p.is_absolute() and ".." not in p.parts and (folder / p).resolve().is_relative_to(folder.resolve())


class _StagingWriter:
    def __init__(self, root: Path, provenance: dict):
        self.root = root
        self.provenance = provenance
        self.written: list[str] = []

    def _path(self, rel: str) -> Path:
        if rel in self.written:  # the second would fail the commit half-way, after the first was moved in
            raise ValueError(f"stage output {rel} written twice")
        p = self.root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        self.written.append(rel)
        return p

    def table(self, rel: str, df: pd.DataFrame, **meta: Any) -> None:
        _write_parquet(self._path(rel), df, {**self.provenance, **meta})

    def figure(self, rel: str, fig) -> None:
        from .plots import plt

        fig.savefig(self._path(rel), dpi=120, bbox_inches="tight")
        plt.close(fig)

    def text(self, rel: str, text: str) -> None:
        self._path(rel).write_text(text)

    def bytes(self, rel: str, data: bytes) -> None:
        self._path(rel).write_bytes(data)

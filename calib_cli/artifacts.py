"""The one module that reads and writes the run directory.

Every artefact is a Parquet file whose schema metadata carries its provenance
(``calib.provenance``: stage, command line, package version, input hashes, settings
hash, fingerprint). Writes are atomic: a stage writes everything into a staging
folder and only then renames each file into place, and its lock file
(``<stage>.lock.json``, in the spirit of DVC's ``dvc.lock``: the stage's fingerprint
and the hash of every output) is written last. A stage whose fingerprint and outputs
are unchanged is skipped; an error before the commit leaves the run directory as it was.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import hashlib
import json
import os
import shlex
import shutil
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from . import __version__
from .errors import CalibError

PROVENANCE_KEY = b"calib.provenance"
LOCK_SUFFIX = ".lock.json"


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
def atomic_write_bytes(path: Path, data: bytes) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
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
    os.close(fd)
    try:
        _write_parquet(Path(tmp), df, provenance)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def read_table(path: Path, columns: Sequence[str] | None = None, what: str = "artefact") -> pd.DataFrame:
    path = Path(path)
    if not path.is_file():
        raise CalibError(f"{what} not found: {path}")
    try:
        df = pq.read_table(path).to_pandas()
    except Exception as e:  # pyarrow raises several types for corrupt files
        raise CalibError(f"{what} {path} is not a readable Parquet file ({type(e).__name__})") from None
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
    return json.loads(raw) if raw else {}


def read_responses(path: Path, factors: Sequence[str], response: str,
                   optional: Sequence[str] = ()) -> pd.DataFrame:
    """A responses table from another engine or a paper: CSV or Parquet.

    Factor columns in natural units plus the response column; every value numeric
    and finite.
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
        raise CalibError(f"responses file {path} could not be read ({type(e).__name__})") from None
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
    return out


def write_json(path: Path, obj: Mapping) -> None:
    atomic_write_bytes(path, json.dumps(_canonical(dict(obj)), indent=2, default=str).encode())


def read_json(path: Path) -> dict:
    try:
        return json.loads(Path(path).read_text())
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
        try:
            return json.loads(self.lock_path.read_text())
        except (OSError, ValueError):
            return None

    def up_to_date(self) -> bool:
        lock = self.read_lock()
        if not lock or lock.get("fingerprint") != self.fingerprint:
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
        self.dir.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(dir=self.dir, prefix=f".{self.name}.staging-"))
        writer = _StagingWriter(staging, self.provenance())
        try:
            yield writer
        except BaseException:
            shutil.rmtree(staging, ignore_errors=True)
            raise
        # commit: rename every output into place, drop stale ones, then the lock
        try:
            old = (self.read_lock() or {}).get("outputs", {})
            hashes = {}
            for rel in writer.written:
                src, dst = staging / rel, self.dir / rel
                dst.parent.mkdir(parents=True, exist_ok=True)
                hashes[rel] = file_hash(src)
                os.replace(src, dst)
            for rel in set(old) - set(hashes):
                with contextlib.suppress(OSError):
                    (self.dir / rel).unlink()
            lock = {"stage": f"{self.group}.{self.name}", "fingerprint": self.fingerprint,
                    "version": __version__, "code": self.code, "command": command_line(),
                    "inputs": self.input_hashes, "settings_hash": self.settings_hash,
                    "outputs": hashes}
            atomic_write_bytes(self.lock_path, json.dumps(lock, indent=2).encode())
        finally:
            shutil.rmtree(staging, ignore_errors=True)


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
        import matplotlib.pyplot as plt

        fig.savefig(self._path(rel), dpi=120, bbox_inches="tight")
        plt.close(fig)

    def text(self, rel: str, text: str) -> None:
        self._path(rel).write_text(text)

    def bytes(self, rel: str, data: bytes) -> None:
        self._path(rel).write_bytes(data)

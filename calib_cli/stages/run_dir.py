"""A run directory: where every stage of one calibration reads and writes (docs/artefacts.md)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

from .. import artifacts as art
from ..errors import CalibError
from ..settings import load_settings, with_overrides
from .common import INITIALISED, SETTINGS_FILE, check_run_dir, writes_run

DEFAULT_TEXT = "# calib settings: built-in defaults (the paper's setup); edit to override\n"


@dataclass
class InitResult:
    """The run's settings file, and whether this call wrote it."""

    path: Path
    wrote: bool
    note: str = ""

    def summary(self) -> str:
        if self.wrote:
            return f"wrote {self.path}" + (f" ({self.note})" if self.note else "")
        return f"{self.path.parent} is initialised ({self.note or self.path})"


@writes_run
def init_run(run: Path, settings: Optional[Path] = None, setting: Optional[list[str]] = None,
             force: bool = False) -> InitResult:
    """Create a run directory with its settings: RUN/settings.toml, a copy of ``settings`` (else the
    built-in defaults) with each KEY=VALUE of ``setting`` written in front of it. An existing, different
    RUN/settings.toml is replaced only with ``force``, or where it is what init last wrote from the same
    ``settings`` file, since edited (a pipeline's settings file); ``setting`` without ``settings`` adds to it."""
    run = check_run_dir(run)
    target = run / SETTINGS_FILE
    settings = Path(settings) if settings is not None else None
    for p in (target, run / INITIALISED):  # a folder there: said before anything is written
        if p.exists() and not p.is_file():
            raise CalibError(f"{p} is a folder, not a file: move it aside")
    load_settings([settings] if settings is not None else [])  # validate before touching the run dir
    if settings is not None:
        text = settings.read_text()
    elif target.is_file() and setting:
        if load_settings([target], setting) == load_settings([target]):
            return InitResult(target, False, f"{target} has {' '.join(setting)} already")
        text = target.read_text()
    else:
        text = None
    if setting:
        text = with_overrides(text if text is not None else DEFAULT_TEXT, setting)
    if target.exists() and (text is None or target.read_text() == text):
        return InitResult(target, False)
    edited = target.exists() and settings is not None and _written_from(run, settings, target)
    if target.exists() and not force and not (setting and settings is None) and not edited:
        raise CalibError(f"{target} exists and differs from --settings: give --force to replace it (the stages "
                         "that depend on a changed setting will then rerun)")
    art.atomic_write_bytes(target, (text if text is not None else DEFAULT_TEXT).encode())
    # a command that later finds no settings file knows it was deleted; and what this call wrote from which
    # file, so that an edit of that file (a pipeline's own settings) replaces it where a hand edit would not
    art.atomic_write_bytes(run / INITIALISED, json.dumps({"source": str(settings.resolve()) if settings else None,
                                                          "written": art.file_hash(target)}).encode())
    return InitResult(target, True, f"{settings} changed since it was copied" if edited else "")


def _written_from(run: Path, settings: Path, target: Path) -> bool:
    """Whether RUN/settings.toml is, unedited, what init last wrote from this same ``settings`` file."""
    try:
        said = json.loads((run / INITIALISED).read_text() or "{}")
    except (OSError, ValueError):
        return False
    return isinstance(said, dict) and said.get("source") == str(settings.resolve()) \
        and said.get("written") == art.file_hash(target)

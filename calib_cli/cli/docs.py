"""The generated parts of docs/ (``make docs``).

- docs/cli.md from the commands' help: typer's generator escapes it for HTML, which a Markdown viewer
  shows verbatim inside code spans (``<path>`` as ``&lt;path&gt;``) and in apostrophes.
- Output blocks: a block between ``<!-- output: KIND RUN [key=value ...] -->`` and ``<!-- end output
  -->`` is what the command that wrote RUN's files prints, rendered again from those files (the tables
  as the command prints them, after the command line read from the files' provenance). A block that no
  longer matches its run is stale: ``python -m calib_cli.cli.docs outputs FILE --check`` says which, and
  tests/test_docs_outputs.py fails on it.
"""

from __future__ import annotations

import html
import io
import re
import sys
from pathlib import Path
from typing import Callable

WIDTH = 120
#: a block's body stops at its own end: it cannot run on into the next block's head
BLOCK = re.compile(r"(?P<head><!-- output: (?P<spec>[^>]*?) -->\n```text\n)"
                   r"(?P<body>(?:(?!<!-- (?:end )?output).)*?)(?P<tail>```\n<!-- end output -->)", re.S)


def unescape_markdown(text: str) -> str:
    """Apostrophes and quotes everywhere; every entity inside a code span (rendered literally there).
    Outside code spans ``&lt;`` stays: a bare ``<a>`` would be read as an HTML tag and vanish."""
    text = text.replace("&#x27;", "'").replace("&quot;", '"')
    return re.sub(r"`[^`\n]*`", lambda m: html.unescape(m.group(0)), text)


# ------------------------------------------------------------------ what each kind of block shows
def _measure(run: Path, out) -> str:
    from ..stages.measure import MeasureResult
    from .measure_cmd import show_conditions

    r = MeasureResult(_stage(run, "measure", "angles"))
    show_conditions(r, out)
    return "measure/conditions.parquet"


def _calibrate(run: Path, out, revision: str | None = None, rounds: str = "yes") -> str:
    """The answer and the rounds of the run's current revision; of an earlier ``revision``, its last round's
    posterior (the answer sampled longer was replaced in posterior/ by the later revision's)."""
    from .. import artifacts as art
    from ..errors import CalibError
    from ..stages.calibrate import CalibrateResult
    from .calibrate_cmd import show_answer, show_calibration

    r = CalibrateResult(_stage(run, "calibrate", "rounds"))
    if revision is not None:
        r = r.at_revision(int(revision))
    made = r.answer
    revision_of = int(art.read_provenance(run / made).get("model_revision", r.revision))
    if revision_of != r.revision:  # calibrate-posterior wrote it since: not this calibration's answer
        raise CalibError(f"{run / made} holds revision {revision_of}'s posterior, not calibrate's of revision "
                         f"{r.revision}")
    (show_calibration if rounds == "yes" else show_answer)(r, out)
    return made


def _compare(run: Path, out, history: str = "no") -> str:
    from ..stages.compare import CompareResult
    from .discrepancy_cmds import show_comparison, show_history

    r = CompareResult(_stage(run, "compare", "residuals"))
    (show_history if history == "yes" else show_comparison)(r, out)
    return "compare/residuals.parquet"


def _diagnose(run: Path, out) -> str:
    from ..stages.diagnose import DiagnoseResult
    from .discrepancy_cmds import show_ranking

    show_ranking(DiagnoseResult(_stage(run, "diagnose", "rank")), out)
    return "diagnose/ranking.parquet"


def _suggest(run: Path, out, top: str = "5") -> str:
    from ..stages.suggest import SuggestResult
    from .discrepancy_cmds import show_suggestions

    show_suggestions(SuggestResult(_stage(run, "suggest", "rank"), top=int(top)), out)
    return "suggest/ranking.parquet"


KINDS: dict[str, Callable[..., str]] = {"measure": _measure, "calibrate": _calibrate, "compare": _compare,
                                        "diagnose": _diagnose, "suggest": _suggest}


def _stage(run: Path, group: str, name: str):
    from .. import artifacts as art

    return art.Stage(run, group, name)


# ------------------------------------------------------------------ blocks
def render(spec: str, root: Path) -> str:
    """A block's text: ``$ command`` (from the provenance of the file it shows), then what it prints."""
    from rich.console import Console

    from .. import artifacts as art
    from ..errors import CalibError

    kind, run, *opts = spec.split()
    if kind not in KINDS:
        raise CalibError(f"output block {spec!r}: unknown kind {kind!r}; known: {', '.join(KINDS)}")
    out = Console(width=WIDTH, file=io.StringIO(), record=True, color_system=None, highlight=False,
                  soft_wrap=False)
    made = KINDS[kind](root / run, out, **dict(o.split("=", 1) for o in opts))
    command = art.read_provenance(root / run / made).get("command", "")
    text = out.export_text(styles=False)
    lines = [ln.rstrip() for ln in text.splitlines()]
    return (f"$ {command}\n" if command else "") + "\n".join(lines).strip("\n") + "\n"


def refresh(text: str, root: Path) -> tuple[str, list[str]]:
    """``text`` with every output block rendered again, and the specs of the blocks that changed."""
    from ..errors import CalibError

    stale: list[str] = []
    if text.count("<!-- output:") != len(BLOCK.findall(text)):
        raise CalibError("an output block lacks its ```text fence or its <!-- end output --> line")

    def one(m: re.Match) -> str:
        body = render(m["spec"], root)
        if body != m["body"]:
            stale.append(m["spec"])
        return m["head"] + body + m["tail"]

    return BLOCK.sub(one, text), stale


def _outputs(paths: list[str], check: bool) -> int:
    root = Path(__file__).resolve().parents[2]
    bad = 0
    for p in map(Path, paths):
        new, stale = refresh(p.read_text(), root)
        for spec in stale:
            print(f"{p}: output block '{spec}' is {'stale' if check else 'rewritten'}")
        bad += len(stale)
        if not check and stale:
            p.write_text(new)
    return 1 if check and bad else 0


if __name__ == "__main__":
    if len(sys.argv) < 2 or sys.argv[1] in ("-h", "--help"):
        print("usage: python -m calib_cli.cli.docs outputs [--check] FILE.md ...  (render the output blocks again)\n"
              "       python -m calib_cli.cli.docs docs/cli.md  (unescape typer's markdown)")
        sys.exit(0 if len(sys.argv) > 1 else 2)
    if sys.argv[1] == "outputs":
        args = [a for a in sys.argv[2:] if a != "--check"]
        sys.exit(_outputs(args, "--check" in sys.argv))
    path = Path(sys.argv[1])
    path.write_text(unescape_markdown(path.read_text()))

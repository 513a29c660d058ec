"""The `calib` command line: one subcommand per stage, thin wrappers over the library."""

from __future__ import annotations

import os
import sys

import typer

from .. import __version__
from .. import artifacts as art
from ..stages.run_dir import init_run
from .common import (ForceOpt, RunOpt, SettingOpt, SettingsOpt, check_run_dir, console, err_console,
                     handle_errors)
from .discrepancy_cmds import compare, diagnose, model_app, synth_lab
from .doe_cmds import ascent_app, bbd_app, pb_app
from .measure_cmd import measure_angle
from .run_cmd import run_pipeline
from .simulate_cmd import simulate_heap
from .surrogate_cmds import fit_surrogate, invert, predict

app = typer.Typer(
    name="calib",
    help="Calibrate DEM contact parameters of wet granular material from heap (angle-of-repose) tests.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
app.add_typer(pb_app, name="pb")
app.add_typer(ascent_app, name="ascent")
app.add_typer(bbd_app, name="bbd")
app.command("measure-angle")(handle_errors(measure_angle))
app.command("simulate-heap")(handle_errors(simulate_heap))
app.command("fit-surrogate")(handle_errors(fit_surrogate))
app.command("predict")(handle_errors(predict))
app.command("invert")(handle_errors(invert))
app.add_typer(model_app, name="model")
app.command("compare")(handle_errors(compare))
app.command("diagnose")(handle_errors(diagnose))
app.command("synth-lab")(handle_errors(synth_lab))
app.command("run")(handle_errors(run_pipeline))


def _version(value: bool):
    if value:
        console.print(f"calib {__version__}")
        raise typer.Exit()


@app.callback()
def _root(version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                       help="Print the version and exit.")):
    pass


@app.command("init")
@handle_errors
def init(run: RunOpt, settings: SettingsOpt = None, setting: SettingOpt = None, force: ForceOpt = False):
    """Create a run directory with its settings: RUN/settings.toml, a copy of --settings (else the
    built-in defaults), with each -s KEY=VALUE written in front of it, e.g. -s heap.shear_modulus=1.5e8
    for a run whose heaps are all simulated at 150 MPa. An existing, different RUN/settings.toml is
    replaced only with --force; -s without --settings adds to it."""
    r = init_run(run, settings, setting, force)
    if r.wrote:
        console.print(f"[green]✓[/] wrote {r.path}")
    else:
        console.print(f"[green]✓[/] {r.summary()}")


@app.command("report")
@handle_errors
def report(run: RunOpt):
    """Write RUN/report.html: every stage's summary tables and plots on one page, for sharing."""
    from ..report import build_report

    run = check_run_dir(run)
    page = build_report(run).encode()
    target = run / "report.html"
    if target.is_file() and target.read_bytes() == page:
        console.print(f"[green]✓[/] {target} is up to date")
        return
    with art.run_lock(run):
        art.atomic_write_bytes(target, page)
    console.print(f"[green]✓[/] wrote {target}")


def main() -> None:
    """Console-script entry point: no traceback for anything a user can cause.

    typer/click handle usage errors and --help themselves (standalone mode, exit code 2);
    user errors inside commands are CalibError (handle_errors, exit 2); whatever else escapes
    is a bug, reported in one line (exit 70) unless CALIB_DEBUG is set.
    """
    try:
        app()
    except KeyboardInterrupt:
        err_console.print("[bold red]interrupted[/]")
        sys.exit(130)
    except Exception as e:
        if os.environ.get("CALIB_DEBUG"):
            raise
        from rich.markup import escape

        err_console.print(f"[bold red]internal error:[/] {type(e).__name__}: {escape(str(e))} "
                          "(set CALIB_DEBUG=1 for a traceback)")
        sys.exit(70)

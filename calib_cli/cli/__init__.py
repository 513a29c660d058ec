"""The `calib` command line: one subcommand per stage, thin wrappers over the library."""

from __future__ import annotations

import os
import sys

import typer

from .. import __version__
from .common import (CalibCommand, CalibGroup, ForceOpt, RunOpt, SettingOpt, SettingsOpt, check_run_dir, console,
                     err_console, handle_errors)
from .calibrate_cmd import calibrate
from .diff_cmd import diff_runs_cmd
from .discrepancy_cmds import compare, diagnose, model_app, suggest_conditions, synth_lab
from .doe_cmds import ascent_app, bbd_app, pb_app
from .measure_cmd import measure_angle
from .run_cmd import run_pipeline
from .simulate_cmd import simulate_heap
from .surrogate_cmds import calibrate_posterior, fit_surrogate, invert, predict

#: the order `calib --help` lists the commands in: the order a calibration uses them
WORKFLOW = ["init", "run", "measure-angle", "synth-lab", "calibrate", "pb", "ascent", "bbd", "simulate-heap",
            "fit-surrogate", "predict", "invert", "calibrate-posterior", "model", "compare", "diagnose",
            "suggest-conditions", "report", "diff-runs"]


class _InWorkflowOrder(CalibGroup):
    def list_commands(self, ctx):
        return sorted(super().list_commands(ctx), key=lambda c: WORKFLOW.index(c) if c in WORKFLOW else len(WORKFLOW))


app = typer.Typer(
    cls=_InWorkflowOrder,
    name="calib",
    help="Calibrate DEM contact parameters of wet granular material from heap (angle-of-repose) tests.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
# the commands in the order a calibration uses them, grouped as the help lists them
SETUP, MEASURE, CALIBRATE, DESIGN, SIMULATE, SURROGATE, LOOP, REPORT = (
    "Set up", "Measure", "Calibrate", "The paper's chain: design and analyse", "Simulate", "Surrogate and inversion",
    "Compare and diagnose", "Report")


def _add(name: str, fn, panel: str, short: str) -> None:
    app.command(name, cls=CalibCommand, rich_help_panel=panel, short_help=short)(handle_errors(fn))


def _init(run: RunOpt, settings: SettingsOpt = None, setting: SettingOpt = None, force: ForceOpt = False):
    """Create a run directory with its settings: RUN/settings.toml, a copy of --settings (else the
    built-in defaults), with each -s KEY=VALUE set in it, e.g. -s heap.shear_modulus=1.5e8 for a run
    whose heaps are all simulated at 150 MPa. An existing, different RUN/settings.toml is replaced only
    with --force, or where it is what init last copied from the same --settings file, since edited (a
    pipeline's settings: its stages then rerun as their settings changed); -s without --settings adds to
    it."""
    from ..stages.run_dir import init_run

    console.print(f"[green]✓[/] {init_run(run, settings, setting, force).summary()}")


def _report(run: RunOpt):
    """Write RUN/report.html, the answer first: what was calibrated against what and whether it fits,
    the parameters, the fit per condition, the error history, the missing effects and a photograph
    per condition; then the paper's stages and the raw tables (docs/getting-started.md)."""
    from .. import artifacts as art
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


_add("init", _init, SETUP, "Create a run directory with its settings.")
_add("run", run_pipeline, SETUP, "Run a whole chain from a pipeline file, redoing only what changed.")
_add("measure-angle", measure_angle, MEASURE, "Repose angle per photograph and per condition.")
_add("synth-lab", synth_lab, MEASURE, "Synthetic photographs of heaps with known parameters and a hidden effect.")
_add("calibrate", calibrate, CALIBRATE, "Calibrate in rounds: heaps where the posterior is unsure, until it is stable.")
app.add_typer(pb_app, name="pb", rich_help_panel=DESIGN)
app.add_typer(ascent_app, name="ascent", rich_help_panel=DESIGN)
app.add_typer(bbd_app, name="bbd", rich_help_panel=DESIGN)
_add("simulate-heap", simulate_heap, SIMULATE, "Simulate heap tests (a design, or one point) on the built-in DEM.")
_add("fit-surrogate", fit_surrogate, SURROGATE, "Fit RSM, BP and PSO-BP surrogates and compare them held out.")
_add("predict", predict, SURROGATE, "Evaluate the saved surrogates at a point.")
_add("invert", invert, SURROGATE, "GA inversion to the target angle, validated (and corrected) by simulation.")
_add("calibrate-posterior", calibrate_posterior, SURROGATE,
     "Posterior of the model's parameters given every condition (Gaussian process, MCMC).")
app.add_typer(model_app, name="model", rich_help_panel=LOOP)
_add("compare", compare, LOOP, "The calibrated model against the measurements, per condition.")
_add("diagnose", diagnose, LOOP, "Rank the effects missing from the model, with the evidence.")
_add("suggest-conditions", suggest_conditions, LOOP, "The next conditions to measure, ranked by what they would teach.")
_add("report", _report, REPORT, "Write RUN/report.html: the answer first, then every stage.")
_add("diff-runs", diff_runs_cmd, REPORT, "A run's headline numbers beside a reference run's.")


def _version(value: bool):
    if value:
        console.print(f"calib {__version__}")
        raise typer.Exit()


@app.callback()
def _root(version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                       help="Print the version and exit.")):
    pass


def command_root():
    """The `calib` command line as one click command: what a pipeline checks and runs its steps with
    (:func:`calib_cli.cli.pipeline.load_pipeline`)."""
    return typer.main.get_command(app)


def main() -> None:
    """Console-script entry point: no traceback for anything a user can cause.

    a usage error (an unknown option, a value out of its range) is one line naming the command's --help
    (exit code 2); user errors inside commands are CalibError (handle_errors, exit 2); whatever else
    escapes is a bug, reported in one line (exit 70) unless CALIB_DEBUG is set.
    """
    # typer's own click (vendored by recent typer, click itself by older ones): its usage errors' base class
    usage = next(c for c in typer.BadParameter.__mro__ if c.__name__ == "ClickException")
    try:
        # not standalone: click would print a usage error as a box of five lines; here it is one
        code = app(standalone_mode=False)
    except usage as e:
        if any(c.__name__ == "NoArgsIsHelpError" for c in type(e).__mro__):
            e.show()
        else:
            from rich.markup import escape

            err_console.print(f"[bold red]error:[/] {escape(e.format_message())} (calib {_command(e)}--help)",
                              highlight=False, soft_wrap=True)
        sys.exit(e.exit_code)
    except KeyboardInterrupt:
        err_console.print("[bold red]interrupted[/]")
        sys.exit(130)
    except Exception as e:
        if type(e).__name__ == "Abort":  # Ctrl-C outside a command, as click reports it
            err_console.print("[bold red]interrupted[/]")
            sys.exit(130)
        if os.environ.get("CALIB_DEBUG"):
            raise
        from rich.markup import escape

        err_console.print(f"[bold red]internal error:[/] {type(e).__name__}: {escape(str(e))} "
                          "(set CALIB_DEBUG=1 for a traceback)")
        sys.exit(70)
    sys.exit(code if isinstance(code, int) else 0)


def _command(e) -> str:
    """The command a usage error is about, for its --help hint ("compare ", "model add "; "" for calib's own)."""
    ctx, path = getattr(e, "ctx", None), []
    while ctx is not None and ctx.parent is not None:  # the names below the root, whatever the program is called
        path.insert(0, ctx.info_name)
        ctx = ctx.parent
    if not path:  # some errors carry no context (an option missing its values): the command line names it
        group = command_root()
        names = set(getattr(group, "commands", {}))
        for arg in sys.argv[1:]:
            if arg in names:
                path.append(arg)
                group = group.commands[arg]
                names = set(getattr(group, "commands", {}))
            elif path or not arg.startswith("-"):
                break
    return "".join(f"{p} " for p in path)

"""`calib run`: a declared pipeline (stages/*.toml); thin wrapper over calib_cli.cli.pipeline."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.markup import escape

from .common import RunOpt, console, err_console


def run_pipeline(
    ctx: typer.Context,
    pipeline: Annotated[Path, typer.Argument(help="Pipeline TOML: the steps of a chain, each a calib command "
                                             "with its inputs and outputs (e.g. stages/paper.toml).", show_default=False,
                                             metavar="PIPELINE.toml")],
    run: RunOpt,
    var: Annotated[Optional[list[str]], typer.Option("--var", help="Set a variable the pipeline declares (its vars "
                   "table), e.g. --var modulus=5e8 (repeatable; a list variable takes its arguments as one "
                   "shell-quoted string: --var 'heap_options=--repeats 2').")] = None,
    dry_run: Annotated[bool, typer.Option("--dry-run", help="Print the commands it would run, and run none.")] = False,
):
    """Run a pipeline: the calib command of each step, in order, into the run directory. Every command
    skips by itself what is up to date (stage locks) and every simulation what is cached, so
    running a pipeline again resumes one that stopped and redoes only what changed. Prints per
    step whether it ran or was up to date."""
    from .pipeline import PipelineInterrupted, StepFailed, execute, load_pipeline, parse_vars, plan

    planned = plan(load_pipeline(pipeline, run, parse_vars(var), root=ctx.find_root().command))
    if dry_run:
        for line in planned.lines():
            typer.echo(line)
        return
    n = len(planned.steps)

    def start(i, step):
        console.print(f"[bold cyan]>> [{i + 1}/{n}] {escape(step.name)}[/]: {escape(step.command)}",
                      highlight=False, soft_wrap=True)

    def done(i, res):
        console.print(f"[bold cyan]<< {escape(res.step.name)}: {res.status}[/] ({res.seconds:.1f} s)", highlight=False)

    try:
        result = execute(planned, on_start=start, on_done=done)
    except StepFailed as e:
        if e.result.steps:  # what finished before it; none: the one line says it all
            console.print(escape(e.result.summary()), highlight=False, soft_wrap=True)
        raise
    except PipelineInterrupted as e:
        if e.result.steps:
            console.print(escape(e.result.summary()), highlight=False, soft_wrap=True)
        err_console.print(f"[bold red]interrupted[/] in step {escape(e.step.name)!r}: finished stages and heaps are "
                          "kept; run the same command again to resume", highlight=False, soft_wrap=True)
        raise typer.Exit(130) from None
    console.print(escape(result.summary()), highlight=False, soft_wrap=True)

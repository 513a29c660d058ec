"""Declared pipelines: a TOML file lists a chain of `calib` commands, the way DVC's ``dvc.yaml`` does.

A pipeline file (``stages/paper.toml``) holds::

    description = "what the chain does"

    [vars]                       # variables and their defaults; --var KEY=VALUE overrides them
    data = "sample_data/paper"
    heap_options = []            # a list: spliced as several arguments ("{heap_options}" alone)

    [env]                        # environment variables set while the steps run
    CALIB_REUSE = "sample_runs/hidden-effect"

    [[step]]
    name = "init"
    command = ["init", "--run", "{run}"]
    settings = "stages/settings/paper.toml"     # appended as --settings FILE, and an input
    outputs = ["{run}/settings.toml"]

    [[step]]
    name = "pb-analyze"
    command = ["pb", "analyze", "--run", "{run}", "--responses", "{data}/table3_pb.csv"]
    inputs = ["{run}/pb/design.parquet", "{data}/table3_pb.csv"]
    outputs = ["{run}/pb/effects.parquet"]
    overrides = ["pb.alpha=0.1"]                # appended as -s KEY=VALUE each

    [[step]]
    include = "paper-screening.toml"            # that file's steps, here (path relative to this file)
    vars = { data = "{data}" }                  # values for its variables

``{run}`` is the run directory given to ``calib run``. A command argument may also be an optional
group, ``{ when = "modulus", args = ["--shear-modulus", "{modulus}"] }``: its arguments are passed
only when the variable is not empty. Paths (inputs, outputs, settings and the commands' own
arguments) are relative to the working directory, as on the command line.

Every step is run, in order, in this process: each command skips by itself what its stage lock
says is up to date and each simulation campaign skips the heaps it has cached, so running a
pipeline again is how a stopped one resumes. :func:`load_pipeline` reads and checks a file,
:func:`plan` (pure) orders and checks the declared inputs, :func:`execute` runs the plan and
reports per step whether its declared outputs changed ("ran") or not ("up to date").
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import shlex
import sys
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence

from ..errors import CalibError

VAR = re.compile(r"\{([A-Za-z_][A-Za-z0-9_]*)\}")
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")
ENV_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
TOP_KEYS = {"description", "vars", "env", "step"}
STEP_KEYS = {"name", "command", "inputs", "outputs", "settings", "overrides"}
INCLUDE_KEYS = {"include", "vars"}
RAN, UP_TO_DATE = "ran", "up to date"

Value = str | list[str]  # a variable: a string, or a list of arguments


@dataclass(frozen=True)
class Step:
    """One `calib` command of a pipeline, variables substituted."""

    name: str
    argv: tuple[str, ...]  # the command and its arguments, without the program name
    inputs: tuple[str, ...] = ()
    outputs: tuple[str, ...] = ()
    source: str = ""  # the pipeline file that declared it

    @property
    def command(self) -> str:
        return shlex.join(("calib", *self.argv))


@dataclass(frozen=True)
class Pipeline:
    path: Path
    run: str
    steps: tuple[Step, ...]
    env: Mapping[str, str] = field(default_factory=dict)
    variables: Mapping[str, Value] = field(default_factory=dict)
    description: str = ""
    #: the `calib` command line (a click command) that checks and runs the steps
    root: Any = None


@dataclass(frozen=True)
class Plan:
    """The steps to run, in order, and the inputs that no step writes (they must exist first)."""

    pipeline: Pipeline
    steps: tuple[Step, ...]
    external: Mapping[str, str]  # input path -> the first step that reads it

    def commands(self) -> list[list[str]]:
        return [list(s.argv) for s in self.steps]

    def lines(self) -> list[str]:
        """The plan as a shell script: what ``calib run --dry-run`` prints."""
        p = self.pipeline
        about = " ".join(p.description.split())  # one comment line, whatever the file's description holds
        head = [f"# {p.path} -> {p.run}: {len(self.steps)} steps" + (f" ({about})" if about else "")]
        env = [f"export {k}={shlex.quote(v)}" for k, v in p.env.items()]
        return head + env + [f"{s.command}  # {s.name}" for s in self.steps]


@dataclass(frozen=True)
class StepResult:
    step: Step
    status: str  # RAN or UP_TO_DATE
    seconds: float
    changed: tuple[str, ...] = ()  # the declared outputs the step created or changed


@dataclass
class PipelineResult:
    plan: Plan
    steps: list[StepResult] = field(default_factory=list)

    @property
    def ran(self) -> list[str]:
        return [r.step.name for r in self.steps if r.status == RAN]

    def summary(self) -> str:
        """One line per step that ran (or was skipped by its command), statsmodels style."""
        p = self.plan.pipeline
        total = sum(r.seconds for r in self.steps)
        done = f"{len(self.steps)} of {len(self.plan.steps)} steps"
        head = (f"pipeline {p.path} -> {p.run}: {done}, {len(self.ran)} ran, "
                f"{len(self.steps) - len(self.ran)} up to date ({total:.1f} s)")
        width = max([len(r.step.name) for r in self.steps] + [4])
        rows = [f"  {'step':<{width}}  {'status':<10}  {'time':>8}  command"]
        rows += [f"  {r.step.name:<{width}}  {r.status:<10}  {r.seconds:>7.1f}s  {r.step.command}" for r in self.steps]
        return "\n".join([head, *rows])


class StepFailed(CalibError):
    """A step's command failed: the message names the step; ``result`` holds the steps before it."""

    def __init__(self, message: str, result: PipelineResult):
        super().__init__(message)
        self.result = result


class PipelineInterrupted(KeyboardInterrupt):
    """Ctrl-C during a step; ``result`` holds the steps before it, ``step`` the one interrupted."""

    def __init__(self, step: Step, result: PipelineResult):
        super().__init__(step.name)
        self.step, self.result = step, result


# ---------------------------------------------------------------- variables
def parse_vars(items: Sequence[str] | None) -> dict[str, str]:
    """``["modulus=5e8"]`` -> ``{"modulus": "5e8"}`` (the values of ``--var KEY=VALUE``)."""
    out: dict[str, str] = {}
    for item in items or ():
        key, eq, value = item.partition("=")
        if not eq or not VAR.fullmatch("{" + key.strip() + "}"):
            raise CalibError(f"--var {item!r} is not KEY=VALUE with KEY a name (letters, digits, _)")
        out[key.strip()] = value
    return out


def _subst(text: str, scope: Mapping[str, Value], where: str) -> str:
    def one(m: re.Match) -> str:
        name = m.group(1)
        if name not in scope:
            raise CalibError(f"{where}: unknown variable {{{name}}} (known: {', '.join(sorted(scope))})")
        value = scope[name]
        if isinstance(value, list):
            raise CalibError(f"{where}: {{{name}}} is a list of arguments: use it as a whole argument")
        return value

    return VAR.sub(one, text)


def _expand(items: Any, scope: Mapping[str, Value], where: str, what: str) -> list[str]:
    """A list of arguments or paths, variables substituted: a list variable that makes up a whole
    item is spliced in, and an optional group ``{when = VAR, args = [...]}`` counts only when VAR
    is not empty."""
    if not isinstance(items, list):
        raise CalibError(f"{where}: {what} must be a list, got {type(items).__name__}")
    out: list[str] = []
    for item in items:
        if isinstance(item, dict):
            if set(item) != {"when", "args"} or not isinstance(item["when"], str):
                raise CalibError(f"{where}: an optional group in {what} is {{when = \"VAR\", args = [...]}}")
            if item["when"] not in scope:
                raise CalibError(f"{where}: unknown variable {item['when']!r} in 'when' "
                                 f"(known: {', '.join(sorted(scope))})")
            if scope[item["when"]]:
                out += _expand(item["args"], scope, where, what)
        elif isinstance(item, str):
            whole = VAR.fullmatch(item)
            value = scope.get(whole.group(1)) if whole else None
            out += value if isinstance(value, list) else [_subst(item, scope, where)]
        else:
            raise CalibError(f"{where}: {what} holds {item!r}: strings only (quote numbers)")
    return out


def _value(raw: Any, where: str, as_list: bool) -> Value:
    """A variable's value from TOML (string, number or list of strings) or from --var (a string,
    split like a shell line when the variable is a list)."""
    if isinstance(raw, bool) or not isinstance(raw, (str, int, float, list)):
        raise CalibError(f"{where}: a variable is a string, a number or a list of strings, got {raw!r}")
    if isinstance(raw, list):
        if not as_list:
            raise CalibError(f"{where}: the variable is a string (its default is), got the list {raw!r}")
        if not all(isinstance(v, str) for v in raw):
            raise CalibError(f"{where}: a list variable holds strings only, got {raw!r}")
        return list(raw)
    if as_list:
        try:
            return shlex.split(str(raw))
        except ValueError as e:
            raise CalibError(f"{where}: {raw!r} is not a list of arguments ({e})") from None
    return str(raw)


def _scope(doc: dict, path: Path, outer: Mapping[str, Value], given: Mapping[str, Value]) -> dict:
    """The variables of one file: the outer ones, then its own [vars] in order (a given value, taken
    as it is > the outer value > the file's default, in which the variables before it are substituted)."""
    declared = doc.get("vars", {})
    if not isinstance(declared, dict):
        raise CalibError(f"{path}: [vars] must be a table")
    if "run" in declared or "run" in given:
        raise CalibError(f"{path}: 'run' is the run directory (--run), not a variable to set")
    unknown = set(given) - set(declared)
    if unknown:
        raise CalibError(f"{path}: unknown variable(s) {', '.join(sorted(unknown))} "
                         f"(declared in [vars]: {', '.join(declared) or 'none'})")
    scope = dict(outer)
    for name, default in declared.items():
        where = f"{path}, variable {name}"
        if not VAR.fullmatch("{" + name + "}"):
            raise CalibError(f"{where}: a variable's name is letters, digits and _")
        is_list = isinstance(default, list)
        if name in given:
            scope[name] = _value(given[name], where, is_list)
        elif name not in outer:
            value = _value(default, where, is_list)
            scope[name] = _expand(value, scope, where, "the value") if is_list else _subst(value, scope, where)
        elif isinstance(outer[name], list) != is_list:  # an including file's variable of the same name
            scope[name] = _value(outer[name], f"{where} (from the including file)", is_list)
    return scope


# ---------------------------------------------------------------- loading
def _read(path: Path) -> dict:
    try:
        if not path.is_file():
            raise CalibError(f"pipeline file not found: {path}" + (" (a folder)" if path.is_dir() else ""))
        text = path.read_text()
    except (OSError, ValueError) as e:  # a name too long, a NUL in it, unreadable: the file's state, not a bug
        raise CalibError(f"pipeline file {str(path)[:200]!r} cannot be read: {e}") from None
    try:
        doc = tomllib.loads(text)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise CalibError(f"pipeline file {path} is not valid TOML: {e}") from None
    except RecursionError:
        raise CalibError(f"pipeline file {path} nests its tables or lists too deep to read") from None
    bad = set(doc) - TOP_KEYS
    if bad:
        raise CalibError(f"{path}: unknown key(s) {', '.join(sorted(bad))} (a pipeline has "
                         f"{', '.join(sorted(TOP_KEYS))})")
    if not isinstance(doc.get("step", []), list) or not doc.get("step"):
        raise CalibError(f"{path}: no steps: declare each as a [[step]] table")
    if not isinstance(doc.get("description", ""), str):  # an included file's too: a typo there is one as well
        raise CalibError(f"{path}: description must be a string, got {type(doc['description']).__name__}")
    return doc


def _step(raw: dict, scope: Mapping[str, Value], path: Path, index: int) -> Step:
    where = f"{path}, step {raw.get('name', index)!s}"
    bad = set(raw) - STEP_KEYS
    missing = [k for k in ("name", "command", "outputs") if k not in raw]
    if bad:
        raise CalibError(f"{where}: unknown key(s) {', '.join(sorted(bad))} (a step has "
                         f"{', '.join(sorted(STEP_KEYS))}, or include and vars)")
    if missing:
        raise CalibError(f"{where}: the step lacks {', '.join(missing)}")
    if not isinstance(raw["name"], str) or not NAME.fullmatch(raw["name"]):
        raise CalibError(f"{where}: a step's name is letters, digits, '_', '.' and '-'")
    argv = _expand(raw["command"], scope, where, "command")
    inputs = _expand(raw.get("inputs", []), scope, where, "inputs")
    if "settings" in raw:
        settings = _expand([raw["settings"]], scope, where, "settings")
        argv += [a for s in settings for a in ("--settings", s)]
        inputs += settings
    for item in _expand(raw.get("overrides", []), scope, where, "overrides"):
        argv += ["-s", item]
    outputs = _expand(raw["outputs"], scope, where, "outputs")
    if any("\0" in x for x in (*argv, *inputs, *outputs)):
        raise CalibError(f"{where}: an argument or path holds a NUL character")
    if not argv:
        raise CalibError(f"{where}: the command is empty")
    if not outputs:
        raise CalibError(f"{where}: declare at least one output (how the step reports whether it ran)")
    norm = lambda ps: tuple(os.path.normpath(p) for p in ps)  # noqa: E731
    return Step(raw["name"], tuple(argv), norm(inputs), norm(outputs), str(path))


def _steps(path: Path, outer: Mapping[str, Value], given: Mapping[str, Value],
           stack: tuple[Path, ...]) -> tuple[list[Step], dict[str, str], dict[str, Value], str]:
    """The steps of one file (includes expanded), its environment, its variables and its description."""
    doc = _read(path)  # first: a path that cannot be resolved is refused there, in one line
    if path.resolve() in stack:
        raise CalibError(f"{path}: included by itself ({' -> '.join(str(p) for p in (*stack, path.resolve()))})")
    scope = _scope(doc, path, outer, given)
    env = _env(doc, path, scope)
    steps: list[Step] = []
    for i, raw in enumerate(doc["step"], start=1):
        if not isinstance(raw, dict):
            raise CalibError(f"{path}: step {i} is not a table")
        if "include" not in raw:
            steps.append(_step(raw, scope, path, i))
            continue
        if set(raw) - INCLUDE_KEYS or not isinstance(raw["include"], str) or not isinstance(raw.get("vars", {}), dict):
            raise CalibError(f"{path}, step {i}: an include step has include = \"FILE\" and optionally vars = {{...}}")
        where = f"{path}, step {i} (include {raw['include']})"
        values: dict[str, Value] = {}
        for k, v in raw.get("vars", {}).items():
            _value(v, f"{where}, variable {k}", isinstance(v, list))  # the types [vars] and --var take
            values[k] = _expand(v, scope, where, k) if isinstance(v, list) else _subst(str(v), scope, where)
        inner, inner_env, _, _ = _steps(path.parent / raw["include"], scope, values, (*stack, path.resolve()))
        steps += inner
        clash = sorted(k for k in set(inner_env) & set(env) if inner_env[k] != env[k])
        if clash:  # every step runs under one environment: one of the two would be dropped unsaid
            raise CalibError(f"{where}: [env] {', '.join(clash)} differs from this file's or an earlier include's "
                             f"({'; '.join(f'{inner_env[k]!r} against {env[k]!r}' for k in clash)})")
        env = {**inner_env, **env}
    return steps, env, scope, doc.get("description", "")


def _env(doc: dict, path: Path, scope: Mapping[str, Value]) -> dict[str, str]:
    """A file's [env], variables substituted: names a shell and os.environ take, values without NUL."""
    env = doc.get("env", {})
    if not isinstance(env, dict) or not all(isinstance(v, str) for v in env.values()):
        raise CalibError(f"{path}: [env] must be a table of strings")
    out = {}
    for k, v in env.items():
        if not ENV_NAME.fullmatch(k):
            raise CalibError(f"{path}: [env] name {k!r} is not an environment variable's (letters, digits, _)")
        out[k] = _subst(v, scope, f"{path}, env {k}")
        if "\0" in out[k]:
            raise CalibError(f"{path}: [env] {k} holds a NUL character")
    return out


def load_pipeline(path: Path | str, run: Path | str, variables: Mapping[str, str] | None = None, *, root) -> Pipeline:
    """Read and check a pipeline file: its structure, its variables (``variables`` overrides the
    file's [vars]; ``{run}`` is ``run``), unique step names, and every step's command against the
    `calib` command line ``root`` (:func:`calib_cli.cli.command_root`; a known command, known options,
    valid values). The command line is given, not imported: it imports this module."""
    path, run = Path(path), str(run)
    if not run.strip():
        raise CalibError("--run is empty: give the run directory")
    steps, env, scope, description = _steps(path, {"run": run}, dict(variables or {}), ())
    seen: dict[str, str] = {}
    for s in steps:
        if s.name in seen:
            raise CalibError(f"{path}: two steps are named {s.name!r} ({seen[s.name]} and {s.source})")
        seen[s.name] = s.source
    for s in steps:
        check_command(root, s)
    return Pipeline(path, run, tuple(steps), env, scope, description, root)


def _click():
    """The click that typer builds its commands on (typer 0.2x carries its own copy, typer._click)."""
    try:
        from typer import _click as click
    except ImportError:  # typer before it carried one
        import click
    return click


def check_command(root, step: Step) -> None:
    """The step's command is a `calib` command (not `run`) and its options parse."""
    click = _click()

    where = f"{step.source}, step {step.name}"
    cmd, args, names = root, list(step.argv), []
    ctx = click.Context(root, info_name="calib")
    while callable(getattr(cmd, "get_command", None)):  # a group (typer's own click has no Group class)
        if not args or args[0].startswith("-"):
            raise CalibError(f"{where}: {shlex.join(['calib', *names])} needs a subcommand "
                             f"({', '.join(cmd.list_commands(ctx))})")
        sub = cmd.get_command(ctx, args[0])
        if sub is None:
            raise CalibError(f"{where}: unknown command {shlex.join(['calib', *names, args[0]])!r} "
                             f"(known: {', '.join(cmd.list_commands(ctx))})")
        names.append(args.pop(0))
        ctx = click.Context(sub, info_name=names[-1], parent=ctx)
        cmd = sub
    if names == ["run"]:
        raise CalibError(f"{where}: a step cannot run another pipeline (include its file instead)")
    if "--help" in args:  # click would print the help and exit 0 when the step runs: a pipeline that did nothing
        raise CalibError(f"{where}: {shlex.join(['calib', *names])} is given --help, which runs nothing; take it "
                         "out of the step's command")
    try:
        with cmd.make_context(" ".join(["calib", *names]), args):
            pass
    except click.ClickException as e:
        raise CalibError(f"{where}: {shlex.join(['calib', *names])}: {e.format_message()}") from None


# ---------------------------------------------------------------- planning
def _covers(output: str, path: str) -> bool:
    return path == output or path.startswith(output.rstrip("/") + "/")


def plan(pipeline: Pipeline) -> Plan:
    """Every step, in the declared order (each command decides by its stage lock whether there is
    work). Checks the declared data flow: a step may read what an earlier step writes or what no
    step writes (an external input); reading what only itself or a later step writes is an error."""
    steps = pipeline.steps
    external: dict[str, str] = {}
    for i, step in enumerate(steps):
        for path in step.inputs:
            if any(_covers(o, path) for s in steps[:i] for o in s.outputs):
                continue
            writer = next((s for s in steps[i:] if any(_covers(o, path) for o in s.outputs)), None)
            if writer is not None:
                who = "itself" if writer is step else f"the later step {writer.name!r}"
                raise CalibError(f"{pipeline.path}: step {step.name!r} reads {path}, which only {who} writes: "
                                 "order the steps so that a file is written before it is read")
            external.setdefault(path, step.name)
    return Plan(pipeline, steps, external)


# ---------------------------------------------------------------- executing
def _hash(path: Path) -> str | None:
    """A file's content hash; a folder's over its files (hidden ones left out); None if absent."""
    from ..artifacts import file_hash

    if path.is_file():
        return file_hash(path)
    if not path.is_dir():
        return None
    h = hashlib.sha256()
    for p in sorted(path.rglob("*")):
        rel = p.relative_to(path)
        if p.is_file() and not any(part.startswith(".") for part in rel.parts):
            h.update(f"{rel.as_posix()}\0{file_hash(p)}\0".encode())
    return h.hexdigest()[:16]


@contextlib.contextmanager
def _as_command(step: Step, env: Mapping[str, str]) -> Iterator[None]:
    """While a step runs: sys.argv is its own command line (what its provenance and lock record,
    as when it is typed), the pipeline's environment is set, and user errors propagate."""
    from .common import errors_propagate

    argv, saved = sys.argv, {k: os.environ.get(k) for k in env}
    sys.argv = ["calib", *step.argv]
    os.environ.update(env)
    try:
        with errors_propagate():
            yield
    finally:
        sys.argv = argv
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def run_step(root, step: Step, env: Mapping[str, str]) -> tuple[str, float, tuple[str, ...]]:
    """Run one step's command in this process: (status, seconds, changed outputs). A user error
    is a CalibError naming the step (its cause in the same line); Ctrl-C is KeyboardInterrupt."""
    from typer.exceptions import Abort

    from .common import os_error_words

    click = _click()

    where = f"step {step.name!r} ({step.command})"
    before = {p: _hash(Path(p)) for p in step.outputs}
    t0 = time.perf_counter()
    try:
        with _as_command(step, env):
            rc = root.main(args=list(step.argv), prog_name="calib", standalone_mode=False)
    except CalibError as e:
        raise CalibError(f"{where}: {e}") from None
    except click.ClickException as e:
        raise CalibError(f"{where}: {e.format_message()}") from None
    except (Abort, getattr(click.exceptions, "Abort", Abort)):
        raise KeyboardInterrupt from None
    except OSError as e:  # a full disk, a folder where a file belongs: the step named, as for a user error
        said = os_error_words(e)
        if said is None:
            raise
        raise CalibError(f"{where}: {said}") from None
    if rc == 130:
        raise KeyboardInterrupt
    if isinstance(rc, int) and not isinstance(rc, bool) and rc != 0:
        raise CalibError(f"{where} exited with status {rc}")
    seconds = time.perf_counter() - t0
    absent = [p for p in step.outputs if not Path(p).exists()]
    if absent:
        raise CalibError(f"{where} finished without writing its declared output(s) {', '.join(absent)}: "
                         "correct the step's outputs in its pipeline file")
    changed = tuple(p for p in step.outputs if _hash(Path(p)) != before[p])
    return (RAN if changed else UP_TO_DATE), seconds, changed


def execute(plan: Plan, on_start: Callable[[int, Step], None] | None = None,
            on_done: Callable[[int, StepResult], None] | None = None) -> PipelineResult:
    """Run every step of the plan in order, through the `calib` command line in this process.

    Checks first that every external input exists. Raises :class:`StepFailed` (a CalibError, its
    one-line message naming the step) when a step fails, :class:`PipelineInterrupted` on Ctrl-C;
    both carry the result of the steps before. Running the same plan again resumes: the finished
    stages are up to date and the finished heaps cached."""
    result = PipelineResult(plan)
    missing = [(p, s) for p, s in plan.external.items() if not Path(p).exists()]
    if missing:
        path, step = missing[0]
        raise StepFailed(f"{plan.pipeline.path}: step {step!r} reads {path}, which does not exist and which no "
                         f"earlier step writes (paths are relative to the working directory, {Path.cwd()})", result)
    root = plan.pipeline.root
    from .. import artifacts as art  # pandas and pyarrow: not for `calib --help`

    # the run directory is this pipeline's from its first step to its last: another command (a second pipeline
    # with other variables) cannot slip in between two steps; each step takes the same lock again (re-entrant)
    with art.run_lock(Path(plan.pipeline.run)):
        for i, step in enumerate(plan.steps):
            try:
                if on_start:
                    on_start(i, step)
                status, seconds, changed = run_step(root, step, plan.pipeline.env)
                result.steps.append(StepResult(step, status, seconds, changed))
                if on_done:
                    on_done(i, result.steps[-1])
            except KeyboardInterrupt:  # in a step, or between two
                raise PipelineInterrupted(step, result) from None
            except CalibError as e:
                done = "the steps before it are done; rerun to resume" if i else "nothing before it ran"
                raise StepFailed(f"{plan.pipeline.path}, {e} ({done})", result) from None
    return result

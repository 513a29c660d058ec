"""The package's layers hold (issue: a shape that stays easy to change): the import-linter contracts of
pyproject.toml (no stage imports another stage; the CLI on top; the library below it) and no import
cycle between modules."""

from __future__ import annotations

import sys

import grimp

from conftest import ROOT


def test_the_import_contracts_are_kept(monkeypatch, capsys):
    from importlinter import cli

    monkeypatch.chdir(ROOT)
    code = cli.lint_imports(config_filename=str(ROOT / "pyproject.toml"), no_cache=True)
    assert code == 0, capsys.readouterr().out[-3000:]


def test_no_module_imports_itself_round_a_cycle():
    """Strongly connected components of the module graph (lazy imports inside functions included)."""
    graph = grimp.build_graph("calib_cli")
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.find_modules_directly_imported_by(v):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            part = []
            while True:
                w = stack.pop()
                part.append(w)
                if w == v:
                    break
            if len(part) > 1:
                cycles.append(sorted(part))

    for m in sorted(graph.modules):
        if m not in index:
            visit(m)
    assert not cycles, cycles


def test_one_module_sets_the_plotting_backend():
    """calib_cli/plots.py sets Agg; a module that draws imports plt from it (no import-order games)."""
    setters = [p.relative_to(ROOT).as_posix() for p in (ROOT / "calib_cli").rglob("*.py")
               if "matplotlib.use(" in p.read_text()]
    assert setters == ["calib_cli/plots.py"], setters

"""The structure of the package, read from its own imports (docs/architecture.md, "Layering"):
no import cycles, the hardware drivers never import the simulator, each part imports only what
its layer may."""

import ast
import functools
from pathlib import Path

import pytest

import ambdaq

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)

ROOT = Path(ambdaq.__file__).parent

MAY_IMPORT = {  # part -> the parts it may import (itself always)
    "errors": set(),
    "units": set(),
    "speed": {"errors", "units"},
    "loading": set(),
    "python_can_import": set(),  # the command line's python-can without asammdf
    "roles": set(),
    "output": {"errors"},
    "machines": {"analysis", "units", "errors", "roles"},  # a machine's description and its models
    "analysis": {"units", "errors"},
    "drivers": {"roles", "errors", "units", "speed", "loading"},
    "mcap": {"drivers", "errors"},  # the file format alone
    "documents": {"roles", "drivers", "machines", "output", "errors"},  # the sealed JSON files
    "acquisition": {"roles", "drivers", "mcap", "machines", "analysis", "output", "errors", "units"},  # devices to files
    "daq": {"roles", "mcap", "acquisition", "machines", "output", "errors", "units"},  # the read side
    "sim": {"roles", "drivers", "analysis", "machines", "speed", "units", "errors", "loading"},
    "workflows": {"roles", "drivers", "mcap", "acquisition", "documents", "daq", "analysis", "machines", "speed",
                  "output", "units", "errors"},  # never the simulator: a machine's models are in machines/
    "studies": {"roles", "drivers", "acquisition", "documents", "analysis", "sim", "workflows", "machines", "speed",
                "units", "errors"},  # runs of the simulator a command reports on
    "live": {"roles", "acquisition", "daq", "analysis", "machines", "units"},
    "figures": {"roles", "documents", "daq", "analysis", "machines", "workflows", "units", "errors"},
    "report": {"analysis", "figures", "errors"},  # the commissioning report's page and PDF, from its result
    "cli": {"roles", "drivers", "mcap", "acquisition", "documents", "daq", "analysis", "sim", "workflows", "studies",
            "live", "figures", "report", "machines", "speed", "output", "units", "errors", "loading",
            "python_can_import"},
}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def from_imports(path: Path, tree: ast.AST):
    """Each ``from ... import`` of an ambdaq module in ``path`` (its parsed ``tree``; relative ones
    resolved, inside functions too): (the module it names, the names it imports)."""
    mod = module_name(path)
    package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.startswith("ambdaq"):
                yield target, [a.name for a in node.names]


@functools.lru_cache(maxsize=None)
def parsed(path: Path) -> ast.Module:
    """``path``'s syntax tree, parsed once for every test here (three read each module: 10 s of a
    worker's setup on a loaded host when each parsed it again)."""
    return ast.parse(path.read_text())


def imports(path: Path) -> set[str]:
    """The ambdaq modules ``path`` imports, resolved (relative imports included; a name imported
    from a package counts as its submodule where there is one)."""
    out = set()
    tree = parsed(path)
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith("ambdaq")}
    for target, names in from_imports(path, tree):
        for name in names:
            sub = f"{target}.{name}"
            out.add(sub if (ROOT.parent / (sub.replace(".", "/") + ".py")).exists()
                    or (ROOT.parent / sub.replace(".", "/")).is_dir() else target)
    return out


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    """Every module's ambdaq imports (read when a test here runs, not at collection: 2.5 s a worker)."""
    return {module_name(p): imports(p) for p in ROOT.rglob("*.py")}


def part(mod: str) -> str:
    return mod.split(".")[1] if mod.count(".") else ""


def test_no_import_cycles(graph):
    seen, on_path = set(), []

    def visit(m):
        if m in on_path:
            raise AssertionError("import cycle: " + " -> ".join(on_path[on_path.index(m):] + [m]))
        if m in seen:
            return
        on_path.append(m)
        for n in graph.get(m, ()):
            if n in graph:
                visit(n)
        on_path.pop()
        seen.add(m)

    for m in graph:
        visit(m)


def test_each_part_imports_only_what_its_layer_may(graph):
    wrong = [(m, n) for m, deps in graph.items() for n in deps  # "": the package itself (__version__)
             if part(m) in MAY_IMPORT and part(n) not in ("", part(m)) and part(n) not in MAY_IMPORT[part(m)]]
    assert not wrong, wrong
    # in particular: no hardware driver, and no workflow, imports the simulator (issue 41: a machine's
    # models are read from machines/, which the simulator steps)
    assert not [(m, n) for m, deps in graph.items() for n in deps if part(m) in ("drivers", "workflows") and part(n) == "sim"]


def test_no_host_side_module_takes_the_spindles_axes(graph):
    """Only the spindle's own description (``machines/``) and its simulation (``sim/``, and the
    studies run on it, ``studies/``) import ``ambdaq.machines.spindle``: every host-side part (daq,
    workflows, live, cli ...) takes its axes, bearings and signals from the recording's machine
    (issue 27)."""
    wrong = sorted(m for m, deps in graph.items()
                   if "ambdaq.machines.spindle" in deps and part(m) not in ("machines", "sim", "studies"))
    assert not wrong, wrong


@functools.lru_cache(maxsize=None)
def _defined(path: Path) -> frozenset[str]:
    """The names a module defines or imports at its top level (what ``from it import NAME`` finds);
    each module parsed once (its importers ask for it again and again)."""
    names = set()
    for node in parsed(path).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            for t in node.targets if isinstance(node, ast.Assign) else [node.target]:
                names |= {n.id for n in ast.walk(t) if isinstance(n, ast.Name)}
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names |= {(a.asname or a.name).split(".")[0] for a in node.names}
    return frozenset(names)


def test_every_name_imported_from_ambdaq_is_there():
    """Each ``from ambdaq.X import NAME`` (relative ones too, inside functions too) names a module
    or package that exists and a submodule or top-level name it has: a renamed module's last
    importer fails here, not in the subprocess a user starts (``from . import profiles`` outlived
    the rename of ``drivers/can/profiles.py`` by a commit)."""
    missing = []
    for path in ROOT.rglob("*.py"):
        for target, names in from_imports(path, parsed(path)):
            where = ROOT.parent / target.replace(".", "/")
            source = where.with_suffix(".py") if where.with_suffix(".py").exists() else where / "__init__.py"
            if not source.exists():
                missing.append((module_name(path), target))
                continue
            defined = _defined(source)
            missing += [(module_name(path), f"{target}.{name}") for name in names
                        if name != "*" and name not in defined and not (where / name).is_dir()
                        and not (where / name).with_suffix(".py").exists()]
    assert not missing, missing

"""Package layering (docs/developer/conventions.md, "Package boundaries"), read from the source with ``ast``.

Every module's imports are read, those inside functions too, so that an import hidden in a
function cannot break a layer unseen. Three rules:

1. A maths module (everything but ``cvsflow.io``, ``cvsflow.plots``, ``cvsflow.cli`` and the
   ``cvsflow.synth`` renderer package) never reaches, directly or through other modules, I/O,
   plotting, matplotlib, snakemake or a file-format library.
2. No import cycle anywhere in the package.
3. Maths modules import other cvsflow modules at module top, where a reader sees them.

A case that cannot pass yet because of a module another engineer owns this round is marked
``xfail(strict=True)`` with its reason, so that it fails (and must be unmarked) once fixed.
"""

from __future__ import annotations

import ast
import functools
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "cvsflow"

#: Layers a maths module must not reach (module-name prefixes).
FORBIDDEN = ("cvsflow.io", "cvsflow.plots", "cvsflow.cli", "matplotlib", "snakemake", "ezc3d")
#: Edge modules: they may do I/O and plotting. ``cvsflow.synth.render`` renders a session to
#: files through ``cvsflow.io.synth_out``, ``cvsflow.synth.flight_video`` a flight's video;
#: ``cvsflow.workflow.scripts`` are the rules' adapters (read, call one function, write).
EDGES = ("cvsflow.io", "cvsflow.plots", "cvsflow.cli", "cvsflow.synth.render",
         "cvsflow.synth.flight_video", "cvsflow.workflow.scripts")

#: Known violations in modules not owned this round: module -> reason (rules 1 and 3).
REACHES_IO_YET: dict = {}
INNER_IMPORTS_YET: dict = {}


def _module_names():
    """Dotted name -> path of every module of the package."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _module_names()


def _resolve(name):
    """The longest prefix of a dotted cvsflow name that is a module of the package."""
    parts = name.split(".")
    while parts and ".".join(parts) not in MODULES:
        parts.pop()
    return ".".join(parts) if parts else name


@functools.cache
def _imports(module):
    """Imports of a module as (target, line, inside_function); cvsflow targets are modules."""
    path = MODULES[module]
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = []

    def visit(node, in_function):
        for child in ast.iter_child_nodes(node):
            inner = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef))
            if isinstance(child, ast.Import):
                found.extend((a.name, child.lineno, in_function) for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:  # relative: from .x import y
                    up = package.split(".")[: len(package.split(".")) - child.level + 1]
                    base = ".".join(up + ([base] if base else []))
                for a in child.names:
                    full = f"{base}.{a.name}"
                    found.append((full if full in MODULES else base, child.lineno, in_function))
            visit(child, inner)

    visit(ast.parse(path.read_text(), str(path)), False)
    return tuple((_resolve(t) if t.startswith("cvsflow") else t, line, inner) for t, line, inner in found)


def _edges():
    """Module -> cvsflow modules it imports (anywhere in the file)."""
    return {
        m: {t for t, _, _ in _imports(m) if t.startswith("cvsflow") and t != m} for m in MODULES
    }


def _is_edge(module):
    return any(module == e or module.startswith(e + ".") for e in EDGES) and module not in REACHES_IO_YET


def _forbidden(name):
    return any(name == f or name.startswith(f + ".") for f in FORBIDDEN)


def _parents(module):
    """Packages Python imports before ``module`` (cvsflow.a.b -> cvsflow, cvsflow.a)."""
    parts = module.split(".")
    return [".".join(parts[:k]) for k in range(1, len(parts))]


def _reach(module):
    """Path to the first forbidden import reachable from ``module``, or None."""
    edges = _edges()
    seen, stack = {module}, [[module]]
    while stack:
        chain = stack.pop()
        here = chain[-1]
        for target, line, _ in _imports(here):
            if _forbidden(target):
                return chain + [f"{target} (line {line})"]
        for nxt in sorted(edges[here] | set(_parents(here))):
            if nxt not in seen:
                seen.add(nxt)
                stack.append(chain + [nxt])
    return None


MATHS = sorted(m for m in MODULES if not _is_edge(m))


def _case(module, known):
    reason = known.get(module)
    return pytest.param(module, marks=pytest.mark.xfail(strict=True, reason=reason)) if reason else module


def test_the_scan_sees_the_package():
    """The scan finds the modules and their imports, those inside functions too."""
    assert {"cvsflow.geometry.rigid", "cvsflow.metrics.errors", "cvsflow.evaluate.heldout", "cvsflow.io.files"} <= set(MODULES)
    assert ("matplotlib.pyplot", True) in {(t, inner) for t, _, inner in _imports("cvsflow.io.files")}
    assert "cvsflow.geometry" in _edges()["cvsflow.mocap.bodies"]
    assert {"cvsflow.evaluate.heldout", "cvsflow.uncertainty", "cvsflow.geometry.transforms", "cvsflow.metrics.errors"} <= set(MATHS)
    assert _reach("cvsflow.plots.mocap")[-1].startswith("matplotlib")


@pytest.mark.parametrize("module", [_case(m, REACHES_IO_YET) for m in MATHS])
def test_maths_module_reaches_no_io_or_plotting(module):
    """No chain of imports (top level or inside functions, package inits included) leads from
    a maths module to cvsflow.io, cvsflow.plots, cvsflow.cli, matplotlib, snakemake or ezc3d."""
    chain = _reach(module)
    assert chain is None, " -> ".join(chain)


def test_no_import_cycle():
    """The import graph (imports inside functions included) has no cycle."""
    edges = _edges()
    index, low, on_stack, stack, cycles = {}, {}, set(), [], []

    def strongconnect(v):  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges[v]):
            if w not in index:
                strongconnect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            strongconnect(v)
    assert cycles == [], f"import cycles: {cycles}"


def test_cycle_check_finds_a_cycle(monkeypatch):
    """The cycle check is not vacuous: a made-up back edge metrics -> evaluate is a cycle."""
    real = _edges()
    fake = {m: set(t) for m, t in real.items()}
    fake["cvsflow.metrics.errors"].add("cvsflow.evaluate.heldout")
    monkeypatch.setitem(globals(), "_edges", lambda: fake)
    with pytest.raises(AssertionError, match="cvsflow.evaluate.heldout"):
        test_no_import_cycle()


@pytest.mark.parametrize("module", [_case(m, INNER_IMPORTS_YET) for m in MATHS])
def test_maths_module_imports_cvsflow_at_top(module):
    """cvsflow imports at module top, where a reader (and this test) sees them first."""
    inner = [f"{t} (line {line})" for t, line, in_fn in _imports(module) if in_fn and t.startswith("cvsflow")]
    assert inner == []


def test_maths_modules_load_no_io_at_run_time():
    """Importing every maths module (synth's aside, see REACHES_IO_YET) in a fresh interpreter
    loads neither cvsflow.io, cvsflow.plots, matplotlib, snakemake nor ezc3d: the run-time
    counterpart of the source scan (catches importlib tricks)."""
    mods = [m for m in MATHS if m not in REACHES_IO_YET]
    code = (
        f"import importlib, sys\nfor m in {mods!r}:\n    importlib.import_module(m)\n"
        f"print([m for m in sys.modules if m.startswith({FORBIDDEN!r})])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=PACKAGE.parent)
    assert out.stdout.strip() == "[]"


def test_reach_check_finds_an_import_hidden_in_a_function(monkeypatch):
    """The reach check is not vacuous: a made-up ``import cvsflow.io.files`` inside a function
    of cvsflow.metrics.errors is found, through evaluate, which imports metrics."""
    real = _imports

    def fake(module):
        extra = (("cvsflow.io.files", 99, True),) if module == "cvsflow.metrics.errors" else ()
        return real(module) + extra

    monkeypatch.setitem(globals(), "_imports", fake)
    chain = _reach("cvsflow.evaluate.heldout")
    assert chain is not None and "cvsflow.metrics.errors" in chain and chain[-1].startswith("cvsflow.io.files")


#: Subpackages imported by module, never through a face: each job loads only the formats,
#: figures and renderers it uses (and exceptions is one module).
BY_MODULE = ("cvsflow.exceptions", "cvsflow.io", "cvsflow.plots", "cvsflow.synth", "cvsflow.cli",
             "cvsflow.workflow")


def _subpackage(module):
    """The stage subpackage a module belongs to: cvsflow.corners.track -> cvsflow.corners."""
    return ".".join(module.split(".")[:2])


def _package_edges():
    """Subpackage -> the subpackages its modules import."""
    out = {}
    for m, targets in _edges().items():
        out.setdefault(_subpackage(m), set()).update(
            _subpackage(t) for t in targets if _subpackage(t) != _subpackage(m))
    return out


def test_no_cycle_between_subpackages():
    """The subpackages import each other in one direction: no chain leads from one back to itself."""
    edges = _package_edges()
    for start in edges:
        seen, stack = set(), [[start]]
        while stack:
            chain = stack.pop()
            for nxt in sorted(edges.get(chain[-1], ())):
                assert nxt != start, "subpackage cycle: " + " -> ".join(chain + [nxt])
                if nxt not in seen:
                    seen.add(nxt)
                    stack.append(chain + [nxt])


def _cross_package_imports():
    """(importer, line, imported module, names) of every `from cvsflow.x.y import ...` that leaves
    the importer's subpackage."""
    out = []
    for module, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if (isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("cvsflow.")
                    and _subpackage(node.module) != _subpackage(module)):
                out.append((module, node.lineno, node.module, [a.name for a in node.names]))
    return out


def test_other_subpackages_are_reached_through_their_face():
    """A maths subpackage is imported from its __init__ (`from cvsflow.corners import ...`),
    which exports what other packages use; modules inside it stay its own business."""
    bad = [f"{m} line {line}: from {target} import ..." for m, line, target, _ in _cross_package_imports()
           if target != _subpackage(target) and not _subpackage(target).startswith(BY_MODULE)]
    assert bad == []


def test_no_private_name_crosses_a_subpackage():
    """A name with a leading underscore is never imported from another subpackage."""
    bad = [f"{m} line {line}: {n} from {target}" for m, line, target, names in _cross_package_imports()
           for n in names if n.startswith("_")]
    assert bad == []


def test_at_most_twenty_top_level_entries_and_modules_under_600_lines():
    """The package's top level stays a table of contents, and no module outgrows a screenful of
    responsibilities (600 lines)."""
    top = [p for p in PACKAGE.iterdir() if p.name != "__pycache__" and p.name != "__init__.py"
           and (p.is_dir() or p.suffix == ".py")]
    assert len(top) <= 20, sorted(p.name for p in top)
    long = {str(p.relative_to(PACKAGE)): n for p in PACKAGE.rglob("*.py")
            if (n := len(p.read_text().splitlines())) > 600}
    assert long == {}

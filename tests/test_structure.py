"""The shape of the package, checked: no import cycle, imports go downward, small modules
and functions, no import-time side effects (issue 12, "Done when").

The import graph is read from the source with :mod:`ast` (no import is executed), the
same way ``audit.py`` of the redesign reads it: every ``import`` / ``from … import`` of a
``bayes_mr`` module is an edge, including the ones inside functions (a lazy import is
still a dependency), except those under ``if TYPE_CHECKING:`` (never run).
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path


PACKAGE = Path(__file__).resolve().parents[1] / "bayes_mr"
ROOT = PACKAGE.parent

MAX_MODULE_LINES = 450
MAX_FUNCTION_LINES = 80
MAX_ARGUMENTS = 12
#: Decorators of numba-compiled kernels: exempt from the size limits (a kernel is one
#: loop the compiler must see whole, and it cannot take a dataclass).
COMPILED = ("jit", "njit", "hot", "driver")


def _modules() -> dict[str, Path]:
    """Dotted module name → file, for every module of the package."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _runtime_nodes(tree: ast.AST):
    """Every node of ``tree`` except the bodies of ``if TYPE_CHECKING:`` blocks."""
    todo = [tree]
    while todo:
        node = todo.pop()
        yield node
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                todo.extend(child.orelse)
            else:
                todo.append(child)


def _imports(name: str, path: Path) -> set[str]:
    """The package modules that module ``name`` imports."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = set()
    for node in _runtime_nodes(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            # `from pkg import mod` depends on pkg.mod; `from mod import name` on mod
            targets = {f"{module}.{a.name}" for a in node.names if f"{module}.{a.name}" in MODULES}
            out |= targets or {module}
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
    return {m for m in out if m in MODULES and m != name}


GRAPH = {name: _imports(name, path) for name, path in MODULES.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index, low, on, stack, out = {}, {}, set(), [], []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return out


def test_the_cycle_finder_finds_a_cycle():
    """The checker itself: a → b → c → a is found, a tree is not."""
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b", "c"}, "b": {"c"}, "c": set()}) == []


def test_no_import_cycle():
    cycles = _cycles(GRAPH)
    assert not cycles, "import cycles: " + "; ".join(" ↔ ".join(c) for c in cycles)


# --- layers: a module never imports one of a higher layer -----------------------------

#: Lower layer (module prefix) → what it must never import (module prefixes).
FORBIDDEN = {
    "bayes_mr.data": ("bayes_mr.inference", "bayes_mr.selection", "bayes_mr.diagnosis", "bayes_mr.cli",
                      "bayes_mr.mainjob", "bayes_mr.report"),
    "bayes_mr.models": ("bayes_mr.inference", "bayes_mr.selection", "bayes_mr.diagnosis", "bayes_mr.cli",
                        "bayes_mr.mainjob", "bayes_mr.report"),
    "bayes_mr.inference": ("bayes_mr.selection", "bayes_mr.diagnosis", "bayes_mr.cli", "bayes_mr.mainjob"),
}


def _under(module: str, prefix: str) -> bool:
    return module == prefix or module.startswith(prefix + ".")


def test_the_layer_check_matches_whole_names():
    assert _under("bayes_mr.data.io", "bayes_mr.data") and _under("bayes_mr.data", "bayes_mr.data")
    assert not _under("bayes_mr.database", "bayes_mr.data")


def test_lower_layers_never_import_higher_ones():
    wrong = sorted(
        f"{name} imports {target}"
        for name, targets in GRAPH.items()
        for lower, higher in FORBIDDEN.items() if _under(name, lower)
        for target in targets if any(_under(target, h) for h in higher)
    )
    assert not wrong, "\n".join(wrong)


# --- sizes ------------------------------------------------------------------------------


def test_no_module_over_the_line_limit():
    long = {str(p.relative_to(ROOT)): n for p in MODULES.values()
            if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES}
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"


def _compiled(node: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    for deco in node.decorator_list:
        text = ast.unparse(deco)
        head = text.split("(")[0].split(".")[-1]
        if head in COMPILED or "jit" in head:
            return True
    return False


def _oversized_functions() -> list[str]:
    out = []
    for path in MODULES.values():
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) or _compiled(node):
                continue
            lines = node.end_lineno - node.lineno + 1
            a = node.args
            n_args = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs)
            if lines > MAX_FUNCTION_LINES or n_args > MAX_ARGUMENTS:
                out.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name}: {lines} lines, {n_args} arguments")
    return sorted(out)


def test_the_size_check_exempts_compiled_kernels_only():
    src = "@njit(cache=True)\ndef k(" + ", ".join(f"a{i}" for i in range(20)) + "):\n    pass\n" \
          "def f(" + ", ".join(f"a{i}" for i in range(13)) + "):\n    pass\n"
    funcs = [n for n in ast.walk(ast.parse(src)) if isinstance(n, ast.FunctionDef)]
    assert [_compiled(f) for f in funcs] == [True, False]


def test_no_function_over_the_size_limits():
    oversized = _oversized_functions()
    assert not oversized, (f"functions over {MAX_FUNCTION_LINES} lines or {MAX_ARGUMENTS} arguments "
                           "(compiled kernels exempt):\n" + "\n".join(oversized))


# --- no import-time side effects ------------------------------------------------------

_IMPORT_ALL = """
import importlib, sys, matplotlib
matplotlib.use("svg")  # a backend no module of the package would pick
for name in sys.argv[1:]:
    importlib.import_module(name)
    if matplotlib.get_backend().lower() != "svg":
        print(name)
        matplotlib.use("svg")  # go on: name every module that switches it
"""


def test_importing_the_package_leaves_the_matplotlib_backend_alone():
    """Import every module in a fresh interpreter; the user's backend must survive."""
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    proc = subprocess.run([sys.executable, "-c", _IMPORT_ALL, *MODULES], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    culprits = proc.stdout.split()
    assert not culprits, f"importing {', '.join(culprits)} changed matplotlib's backend"


# --- the contract lives in the project ----------------------------------------------------

CONTRACT = ROOT / "docs" / "CONTRACT.md"


def _project_text_files():
    skip = {".git", ".venv", "results", "build", ".pytest_cache"}
    for path in ROOT.rglob("*"):
        rel = path.relative_to(ROOT)
        if path.is_file() and not skip & set(rel.parts) and "golden" not in rel.parts and (
                path.suffix in {".py", ".md", ".toml", ".cfg", ".txt"} or path.name in {"Makefile", "run"}):
            yield rel, path


def test_no_file_points_outside_the_repository():
    """A clone needs nothing beside it: no doc or docstring sends the reader to ../shared."""
    outside = [f"{rel}:{i}" for rel, path in _project_text_files()
               if path != Path(__file__).resolve()  # this test names what it looks for
               for i, line in enumerate(path.read_text(errors="replace").splitlines(), 1)
               if "../shared" in line or "shared/SPEC" in line]
    assert not outside, "references outside the repository: " + ", ".join(outside)


def test_the_contract_names_every_model_effect_and_verb():
    """docs/CONTRACT.md and the code agree on the fixed names (a new one must be documented)."""
    from bayes_mr.cli import VERBS
    from bayes_mr.models import EFFECTS, FORMS

    text = CONTRACT.read_text()
    missing = [name for name in (*FORMS, *EFFECTS, "none") if f"`{name}`" not in text]
    missing += [f"bayes-mr {verb}" for verb in VERBS if f"bayes-mr {verb}" not in text]
    assert not missing, f"not in docs/CONTRACT.md: {missing}"

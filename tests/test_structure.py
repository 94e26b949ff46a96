"""The shape of the package, checked: no import cycle, imports go downward, modules and functions
of a readable size (counted in code lines), no import-time side effects.

The import graph is read from the source with :mod:`ast` (no import is executed): every
``import`` / ``from … import`` of a ``bayes_mr`` module is an edge, including the ones inside
functions (a lazy import is still a dependency) and those under ``if TYPE_CHECKING:`` (a type a
module names is a dependency of its reader, and a cycle through one is still a knot to untie).
"""

from __future__ import annotations

import ast
import io
import os
import subprocess
import sys
import tokenize
from pathlib import Path


PACKAGE = Path(__file__).resolve().parents[1] / "bayes_mr"
ROOT = PACKAGE.parent

#: Sizes are counted in code lines: docstrings, comments and blank lines are free, so a module's
#: prose never pushes its code out.
MAX_MODULE_CODE_LINES = 400
MAX_FUNCTION_CODE_LINES = 70
MAX_ARGUMENTS = 12
#: Decorators of numba-compiled kernels: exempt from the size limits (a kernel is one
#: loop the compiler must see whole, and it cannot take a dataclass).
COMPILED = ("jit", "njit", "hot", "driver")


def _modules() -> dict[str, Path]:
    """Dotted module name → file, for every module of the package (``__main__`` runs the CLI: not a module)."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        if parts[-1] == "__main__":
            continue
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _imports(name: str, path: Path) -> set[str]:
    """The package modules that module ``name`` imports."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
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

#: The packages of bayes_mr from the bottom up, as ``docs/ARCHITECTURE.md`` draws them. A module may
#: import its own layer's packages and lower ones, never a higher layer's.
LAYERS = (
    ("_compile", "numerics", "execution", "report"),
    ("data", "signals"),
    ("models",),
    ("simulation",),
    ("likelihood", "scores"),
    ("inference",),
    ("selection", "diagnosis"),
    ("run", "bench", "storage"),
    ("cli",),
)


def _layer(module: str) -> int | None:
    """Index in :data:`LAYERS` of a module's top package (None: not in the map)."""
    parts = module.split(".")
    if len(parts) == 1:
        return len(LAYERS)  # the package's __init__: the public face, above everything
    return next((i for i, names in enumerate(LAYERS) if parts[1] in names), None)


def test_every_package_is_in_the_map_and_no_module_sits_at_the_top():
    """Only ``__init__`` (the public API) and ``__main__`` live at the top; every package has a layer."""
    loose = sorted(p.name for p in PACKAGE.glob("*.py") if p.name not in {"__init__.py", "__main__.py"})
    assert not loose, f"top-level modules outside a package: {loose}"
    unmapped = sorted({name.split(".")[1] for name in MODULES if "." in name and _layer(name) is None})
    assert not unmapped, f"packages missing from LAYERS (and docs/ARCHITECTURE.md): {unmapped}"
    text = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    undocumented = [name for names in LAYERS for name in names if f"`{name}/`" not in text]
    assert not undocumented, f"packages not named in docs/ARCHITECTURE.md: {undocumented}"


def test_the_layer_check_reads_top_packages():
    assert _layer("bayes_mr.data.quality.report") == 1 and _layer("bayes_mr.cli.commands") == len(LAYERS) - 1
    assert _layer("bayes_mr") == len(LAYERS) and _layer("bayes_mr.nowhere.x") is None


def test_lower_layers_never_import_higher_ones():
    wrong = sorted(f"{name} imports {target}" for name, targets in GRAPH.items()
                   for target in targets if _layer(target) > _layer(name))
    assert not wrong, "\n".join(wrong)


# --- sizes, in code lines ---------------------------------------------------------------


def _docstring_lines(tree: ast.AST) -> set[int]:
    """Lines of string statements: module, class and function docstrings and attribute docstrings."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str):
            out.update(range(node.lineno, node.end_lineno + 1))
    return out


def code_lines(source: str) -> set[int]:
    """Line numbers of ``source`` that hold code: not blank, not only a comment, not in a docstring."""
    lines = set()
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type not in (tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT,
                            tokenize.ENDMARKER):
            lines.update(range(tok.start[0], tok.end[0] + 1))
    return lines - _docstring_lines(ast.parse(source))


def test_code_lines_leave_out_prose():
    src = '"""Doc\n\nmore."""\n\n# a comment\nx = 1  # counted\n\n\ndef f(a):\n    """One."""\n    return (a +\n            1)\n'
    assert sorted(code_lines(src)) == [6, 9, 11, 12]


def test_no_module_over_the_code_line_limit():
    long = {str(p.relative_to(ROOT)): n for p in MODULES.values()
            if (n := len(code_lines(p.read_text()))) > MAX_MODULE_CODE_LINES}
    assert not long, f"modules over {MAX_MODULE_CODE_LINES} code lines: {long}"


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
        source = path.read_text()
        code = code_lines(source)
        for node in ast.walk(ast.parse(source)):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) or _compiled(node):
                continue
            lines = len(code & set(range(node.lineno, node.end_lineno + 1)))
            a = node.args
            n_args = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs)
            if lines > MAX_FUNCTION_CODE_LINES or n_args > MAX_ARGUMENTS:
                out.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name}: {lines} code lines, {n_args} arguments")
    return sorted(out)


def test_the_size_check_exempts_compiled_kernels_only():
    src = "@njit(cache=True)\ndef k(" + ", ".join(f"a{i}" for i in range(20)) + "):\n    pass\n" \
          "def f(" + ", ".join(f"a{i}" for i in range(13)) + "):\n    pass\n"
    funcs = [n for n in ast.walk(ast.parse(src)) if isinstance(n, ast.FunctionDef)]
    assert [_compiled(f) for f in funcs] == [True, False]


def test_no_function_over_the_size_limits():
    oversized = _oversized_functions()
    assert not oversized, (f"functions over {MAX_FUNCTION_CODE_LINES} code lines or {MAX_ARGUMENTS} arguments "
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
    from bayes_mr.cli.commands import VERBS
    from bayes_mr.models import EFFECTS, FORMS

    text = CONTRACT.read_text()
    missing = [name for name in (*FORMS, *EFFECTS, "none") if f"`{name}`" not in text]
    missing += [f"bayes-mr {verb}" for verb in VERBS if f"bayes-mr {verb}" not in text]
    assert not missing, f"not in docs/CONTRACT.md: {missing}"

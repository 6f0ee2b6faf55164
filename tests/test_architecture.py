"""The shape of the package (issue 13): no import cycle among striptri's modules, counting the
imports inside functions too (so no function-level import can be a way round one), and the three
methods as siblings below ``striptri.adjustment`` that import only what lies below them."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE = SRC / "striptri"
METHOD_PACKAGES = ("striptri.conditions_method", "striptri.bundle", "striptri.sequential")


def module_files() -> dict[str, Path]:
    files = {}
    for path in PACKAGE.rglob("*.py"):
        parts = list(path.relative_to(SRC).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        files[".".join(parts)] = path
    return files


def imports_of(name: str, path: Path, modules: dict[str, Path]) -> list[tuple[str, int, bool]]:
    """(imported striptri module, line, at module level?) of every import statement in the file,
    those inside functions included; ``from package import name`` counts as an import of the
    submodule when ``name`` is one, else of the package."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = []
    tree = ast.parse(path.read_text())
    top_level = {id(node) for node in tree.body}
    typing_only = {id(inner) for node in ast.walk(tree) if isinstance(node, ast.If)
                   and getattr(node.test, "id", None) == "TYPE_CHECKING" for inner in ast.walk(node)}
    for node in ast.walk(tree):
        if id(node) in typing_only:  # no import at run time
            continue
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(base + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
        else:
            continue
        for target in targets:
            if target.startswith("striptri") and target in modules and target != name:
                found.append((target, node.lineno, id(node) in top_level))
    return found


def import_graph() -> dict[str, set[str]]:
    modules = module_files()
    return {name: {t for t, _, _ in imports_of(name, path, modules)} for name, path in modules.items()}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_cycle_finder_finds_a_cycle():
    """The check below can fail: a cycle of three and one of two are found, a chain is not."""
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"e"}, "e": {"d"}, "f": {"a"}}
    assert sorted(cycles(graph)) == [["a", "b", "c"], ["d", "e"]]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []


def test_no_import_cycle_in_striptri_counting_imports_inside_functions():
    graph = import_graph()
    assert len(graph) > 80  # every module was read
    assert cycles(graph) == []


def test_the_graph_sees_imports_inside_functions():
    """striptri.cli imports the pipeline inside its commands (start-up time): the graph has it."""
    assert "striptri.pipeline" in import_graph()["striptri.cli.adjust"]


@pytest.mark.parametrize("method", METHOD_PACKAGES)
def test_a_method_imports_no_sibling_and_not_the_dispatcher(method):
    """Each method imports striptri.core and the modules below, never another method or
    striptri.adjustment (which imports them all)."""
    graph = import_graph()
    own = [name for name in graph if name == method or name.startswith(method + ".")]
    assert own
    forbidden = {"striptri.adjustment", *(m for m in METHOD_PACKAGES if m != method)}
    for name in own:
        bad = {t for t in graph[name] if t in forbidden or any(t.startswith(f + ".") for f in forbidden)}
        assert not bad, f"{name} imports {sorted(bad)}"


def test_core_imports_no_method():
    graph = import_graph()
    for name in (n for n in graph if n.startswith("striptri.core")):
        bad = {t for t in graph[name] if t == "striptri.adjustment" or any(
            t == m or t.startswith(m + ".") for m in METHOD_PACKAGES)}
        assert not bad, f"{name} imports {sorted(bad)}"


# ------------------------------------------------------------------ packages (issue 27)

ROOT_MODULES_MAX = 12
LONG_MODULE = 600


def package_of(name: str) -> str:
    """striptri.X for a module of the subpackage X; a module in the root is its own node."""
    parts = name.split(".")
    return ".".join(parts[:2])


def package_graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for name, targets in import_graph().items():
        own = package_of(name)
        graph.setdefault(own, set()).update(package_of(t) for t in targets if package_of(t) != own)
    return graph


def test_no_import_cycle_between_packages():
    """io -> crs -> io and io -> film -> io were cycles at run time that the module graph did not
    show: a cycle of packages is one room's stairs leading into another's and back."""
    graph = package_graph()
    assert len(graph) > 20
    assert cycles(graph) == []


def test_no_module_imports_another_packages_private_names():
    """``from other.package import _name``: an underscored name is its module's own business."""
    modules = module_files()
    bad = []
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.ImportFrom):
                continue
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - (node.level - 1)]
                                + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            if not base.startswith("striptri") or package_of(base) == package_of(name):
                continue
            bad += [f"{name}: {base}.{a.name}" for a in node.names
                    if a.name.startswith("_") and not a.name.endswith("__")]
    assert not bad, bad


def test_few_modules_in_the_root_and_none_over_600_lines():
    modules = module_files()
    root = [n for n, p in modules.items() if n.count(".") == 1 and p.parent == PACKAGE]
    assert len(root) <= ROOT_MODULES_MAX, sorted(root)
    for name, path in modules.items():
        lines = len(path.read_text().splitlines())
        if lines > LONG_MODULE:
            assert lines <= LONG_MODULE, f"{name}: {lines} lines"


def sigma_to_weight_sites(tree: ast.AST) -> list[int]:
    """Lines where a standard deviation becomes a weight by hand: ``x / sigma**2`` (a name that
    holds "sig"), ``1 / sigma``, ``1 / np.sqrt(...)``, ``1 / np.where(...)``, ``x ** -2`` and
    ``1 / q`` of a variance named q_*."""
    def named(node, part):
        return isinstance(node, (ast.Name, ast.Attribute, ast.Subscript, ast.Call)) and part in ast.unparse(node)

    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div):
            right = node.right
            if isinstance(right, ast.BinOp) and isinstance(right.op, ast.Pow) and named(right.left, "sig"):
                lines.append(node.lineno)
            elif (isinstance(node.left, ast.Constant) and isinstance(right, ast.Call)
                  and ast.unparse(right.func) == "np.sqrt"):
                lines.append(node.lineno)
            elif isinstance(node.left, ast.Constant) and (named(right, "sig") or named(right, "q_")
                                                          or ast.unparse(right).startswith("np.where(")):
                lines.append(node.lineno)
        elif (isinstance(node, ast.BinOp) and isinstance(node.op, ast.Pow) and isinstance(node.right, ast.UnaryOp)
              and isinstance(node.right.op, ast.USub)):
            lines.append(node.lineno)
    return lines


WEIGHTS = "striptri.equations.weights"
NOT_A_WEIGHT = {("striptri.solvers.base", "1.0 / np.sqrt(d)")}  # Jacobi scaling of a normal matrix's diagonal


def test_a_sigma_becomes_a_weight_only_in_equations_weights():
    """equations/weights.py is the only place where a standard deviation becomes a weight (issue 27)."""
    found = []
    for name, path in module_files().items():
        if name == WEIGHTS:
            continue
        text = path.read_text()
        source = text.splitlines()
        for line in sigma_to_weight_sites(ast.parse(text)):
            if not any(name == m and snippet in source[line - 1] for m, snippet in NOT_A_WEIGHT):
                found.append(f"{name}:{line}: {source[line - 1].strip()}")
    assert not found, "\n".join(found)


def test_the_weight_finder_finds_the_forms_it_looks_for():
    tree = ast.parse("a = 1.0 / sigma_xy[rows] ** 2\nb = B / s.sigma**2\nc = 1.0 / np.sqrt(q)\nd = f**-2.0\n"
                     "e = 1.0 / q_control\nf = 1.0 / np.where(w, q, 1.0)\ng = (1.0 / sigma)[..., None]\n"
                     "ok = x / y**2 + 1.0 / n\n")
    assert sigma_to_weight_sites(tree) == [1, 2, 3, 4, 5, 6, 7]


PARAMETERS_MAX = 8  # beyond this a function takes an options object (issue 27)


def test_no_function_takes_more_than_eight_parameters():
    """A function with more than PARAMETERS_MAX parameters (self and cls not counted; *args and
    **kwargs not counted: a click command takes its options by name and builds one object of them)
    takes an options object instead."""
    long = []
    for name, path in module_files().items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                a = node.args
                params = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs if x.arg not in ("self", "cls")]
                if len(params) > PARAMETERS_MAX:
                    long.append(f"{name}:{node.lineno} {node.name} ({len(params)})")
    assert not long, "\n".join(long)

"""msta's source files as modules, and their imports, read with ``ast`` (holds no tests).

``tests/conftest.py`` registers it as ``msta_source_tree``. The repository's folders map onto
one import name, ``msta`` (pyproject.toml's ``package-dir``): :data:`FOLDERS` is that map,
and the two LeRobot plugins, distributions of their own, keep their names
(:data:`PLUGINS`). The layer, shape and import tests read the tree through here.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: import package -> the repository folder it is installed from
FOLDERS: dict[str, str] = {
    "msta.data": "msta_data",
    "msta.policies": "policies",
    "msta.collect": "collect",
    "msta.train": "train",
    "msta.eval": "eval",
}
#: the LeRobot plugins: import name -> folder
PLUGINS: dict[str, str] = {
    "lerobot_env_msta": "collect/plugins/lerobot_env_msta/lerobot_env_msta",
    "lerobot_policy_msta": "train/plugins/lerobot_policy_msta/lerobot_policy_msta",
}
#: the names installing msta used to add to site-packages (no module may import them)
OLD_TOP_LEVEL = ("msta_data", "policies", "collect", "train", "eval")


def _walk(package: str, folder: Path, skip: Path | None = None) -> dict[str, Path]:
    out = {}
    for path in sorted(folder.rglob("*.py")):
        rel = path.relative_to(folder)
        if "__pycache__" in rel.parts or "plugins" in rel.parts:
            continue
        parts = list(rel.with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join([package, *parts])] = path
    return out


def modules(root: Path = REPO, plugins: bool = True) -> dict[str, Path]:
    """Every module of the packages (``msta.*``, and the plugins' with ``plugins``) -> file."""
    out: dict[str, Path] = {}
    for package, folder in FOLDERS.items():
        if (root / folder).is_dir():
            out.update(_walk(package, root / folder))
    if plugins:
        for package, folder in PLUGINS.items():
            if (root / folder).is_dir():
                out.update(_walk(package, root / folder))
    return out


def module_of(name: str, known: dict[str, Path]) -> str | None:
    """The module of ``known`` that the dotted ``name`` (a module or a name in one) is."""
    while name and name not in known:
        name = name.rpartition(".")[0]
    return name or None


@dataclass(frozen=True)
class Import:
    """One imported name: ``target`` (dotted, as written, the imported attribute appended for
    ``from M import a``), the line, and where the statement sits."""

    target: str
    line: int
    local: bool  # inside a function body
    type_checking: bool  # under ``if TYPE_CHECKING:``
    statement: ast.Import | ast.ImportFrom


def _type_checking(node: ast.AST) -> bool:
    test = getattr(node, "test", None)
    return isinstance(node, ast.If) and (
        (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING")
        or (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"))


def imports(path: Path) -> list[Import]:
    """Every absolute import of ``path``, at module level, in functions and under
    ``TYPE_CHECKING`` (a relative import is an error: msta writes none)."""
    out: list[Import] = []

    def visit(node: ast.AST, local: bool, tc: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.ImportFrom):
                assert not child.level, f"{path}:{child.lineno}: a relative import"
                out.extend(Import(f"{child.module}.{a.name}", child.lineno, local, tc, child)
                           for a in child.names)
            elif isinstance(child, ast.Import):
                out.extend(Import(a.name, child.lineno, local, tc, child) for a in child.names)
            else:
                visit(child, local or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)),
                      tc or _type_checking(child))

    visit(ast.parse(path.read_text(), str(path)), False, False)
    return out


def import_graph(root: Path = REPO) -> dict[str, set[str]]:
    """module -> the modules of the tree it imports (any kind of import; a package's
    ``__init__`` is the module of its name)."""
    known = modules(root)
    graph: dict[str, set[str]] = {}
    for name, path in known.items():
        targets = {module_of(imp.target, known) for imp in imports(path)}
        graph[name] = {t for t in targets if t is not None and t != name}
    return graph


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import circles of ``graph``: each strongly connected set of two or more modules,
    sorted (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                group = []
                while True:
                    top = stack.pop()
                    on_stack.discard(top)
                    group.append(top)
                    if top == node:
                        break
                if len(group) > 1:
                    found.append(sorted(group))
    return sorted(found)


def defined_names(path: Path) -> set[str]:
    """The names a module defines at its top level (functions, classes, assignments, also
    inside top-level ``if`` / ``try``), not the names it imports."""
    names: set[str] = set()
    for node in ast.parse(path.read_text(), str(path)).body:
        nodes = [node] if not isinstance(node, (ast.If, ast.Try)) else list(ast.walk(node))
        for n in nodes:
            if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                names.add(n.name)
            elif isinstance(n, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
                targets = n.targets if isinstance(n, ast.Assign) else [n.target]
                names.update(x.id for t in targets for x in ast.walk(t)
                             if isinstance(x, ast.Name))
    return names


def imports_not_from_home(root: Path = REPO, extra: tuple[Path, ...] = ()) -> list[str]:
    """``file:line module . name`` for each ``from msta.X import name`` of the tree (and of
    ``extra`` files) that takes ``name`` from a module which only imports it: a name is
    imported from the module that defines it. A package's ``__init__`` (a facade such as
    ``msta.policies.msta``) may re-export."""
    known = modules(root)
    defined = {name: defined_names(path) for name, path in known.items()}
    bad = []
    for path in [*known.values(), *extra]:
        for imp in imports(path):
            node = imp.statement
            if not isinstance(node, ast.ImportFrom) or node.module not in known \
                    or known[node.module].name == "__init__.py" or imp.target in known:
                continue
            name = imp.target.rpartition(".")[2]
            if name not in defined[node.module]:
                bad.append(f"{path.relative_to(root)}:{imp.line} {node.module} . {name}")
    return bad

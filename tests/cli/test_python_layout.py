"""The Python package's layout (issue 26): no import circles between its modules, no module
over about 600 lines without the reason written at its top, and one module per command."""
import ast
import pathlib

import corpuscle
from corpuscle.cli import COMMAND_MODULES, COMMANDS

ROOT = pathlib.Path(corpuscle.__file__).parent
MAX_LINES = 600


def _modules() -> dict[str, pathlib.Path]:
    out = {}
    for f in ROOT.rglob("*.py"):
        parts = ["corpuscle", *f.relative_to(ROOT).with_suffix("").parts]
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = f
    return out


def _imports_at_import_time(name: str, path: pathlib.Path, modules) -> set[str]:
    """The package's modules that ``name`` imports when it is imported (statements outside
    functions and classes; ``from . import sub`` depends on the submodule, not the package)."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    deps = set()
    stack = list(ast.parse(path.read_text(encoding="utf-8")).body)
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            continue
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parts + ([node.module] if node.module else []))
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                deps.add(sub if sub in modules else base)
        elif isinstance(node, ast.Import):
            deps.update(alias.name for alias in node.names)
        else:
            stack.extend(ast.iter_child_nodes(node))
    return {d for d in deps if d in modules and d != name}


def test_no_import_circles():
    modules = _modules()
    graph = {name: _imports_at_import_time(name, path, modules) for name, path in modules.items()}
    circles = []
    state: dict[str, int] = {}

    def visit(node, path):
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                circles.append(" -> ".join(path[path.index(nxt):] + [nxt]))
            elif nxt not in state:
                visit(nxt, path + [nxt])
        state[node] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name, [name])
    assert circles == []
    # the two that were: the scene loader and the kinds, the command line and the polar sweep
    assert "corpuscle.scene" not in graph["corpuscle.kinds"]
    # (that one inside a function): outside the command line only its entry point imports it
    users = []
    for name, path in modules.items():
        if name.startswith("corpuscle.cli") or name in ("corpuscle._entry", "corpuscle.__main__"):
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and ((node.level and (node.module or "").startswith("cli"))
                                                     or (node.module or "").startswith("corpuscle.cli")):
                users.append(name)
    assert users == []


def test_no_long_module_without_a_reason_at_its_top():
    long = []
    for name, path in _modules().items():
        lines = path.read_text(encoding="utf-8").splitlines()
        if len(lines) > MAX_LINES and "longer than 600 lines" not in "\n".join(lines[:40]).lower():
            long.append(f"{name}: {len(lines)} lines")
    assert long == []


def test_each_command_is_a_module_of_the_cli_package():
    assert list(COMMANDS) == list(COMMAND_MODULES)
    for name in COMMAND_MODULES:
        assert (ROOT / "cli" / f"{name}.py").is_file(), name
        assert COMMANDS[name].name == name

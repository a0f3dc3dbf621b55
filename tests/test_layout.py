"""The code's layers, read from its imports (every import, those inside functions too):

- the runtime (hypergs_blender's own modules and io/) imports only itself;
- training/ and bench/ import the runtime (and themselves), commands/ anything of hypergs_blender;
- the Blender glue (ops/, ui/, engine/, com/ and the extension's __init__) imports the runtime and
  itself, never training/, bench/ or commands/;
- no import cycles between modules.
"""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GLUE = ("ops", "ui", "engine", "com")


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def modules() -> dict[str, Path]:
    files = [ROOT / "__init__.py"]
    for top in ("hypergs_blender", *GLUE):
        files += sorted((ROOT / top).rglob("*.py"))
    return {module_name(f): f for f in files}


def imports(name: str, path: Path, known: dict) -> set[str]:
    """Modules of this repository that `name` imports (a `from package import module` counts as an
    import of the module)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            base = package.split(".") if package else []
            if node.level:
                base = base[:len(base) - (node.level - 1)] if node.level > 1 else base
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:
                full = f"{target}.{alias.name}" if target else alias.name
                if full in known:
                    found.add(full)
                elif target in known:
                    found.add(target)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if alias.name in known)
    found.discard(name)
    return found


def layer(name: str) -> str:
    if name == "" or name.split(".")[0] in GLUE:
        return "glue"
    parts = name.split(".")
    if len(parts) > 1 and parts[1] in ("training", "bench", "commands"):
        return parts[1]
    if name == "hypergs_blender.__main__":
        return "commands"
    return "runtime"


ALLOWED = {"runtime": {"runtime"}, "training": {"runtime", "training"}, "bench": {"runtime", "bench"},
           "commands": {"runtime", "training", "bench", "commands"}, "glue": {"runtime", "glue"}}


def graph() -> dict[str, set[str]]:
    known = modules()
    return {name: imports(name, path, known) for name, path in known.items()}


def test_the_graph_sees_the_imports():
    g = graph()
    assert "hypergs_blender.io.frames" in g["hypergs_blender.encode"]
    assert "hypergs_blender.refine" in g["hypergs_blender.encode"]  # an import inside a function
    assert "com.mesh" in g["ops.scene"] and "hypergs_blender.io.hgs" in g["com.linked"]
    assert layer("ops.scene") == "glue" and layer("hypergs_blender.io.hgs") == "runtime"
    assert layer("hypergs_blender.training.train") == "training" and layer("") == "glue"


def test_no_import_reaches_a_higher_layer():
    wrong = [f"{a} ({layer(a)}) imports {b} ({layer(b)})" for a, targets in graph().items() for b in sorted(targets)
             if layer(b) not in ALLOWED[layer(a)]]
    assert not wrong, "\n".join(wrong)


def test_no_import_cycles():
    g = graph()
    state, stack, cycles = {}, [], []

    def visit(node):
        state[node] = "open"
        stack.append(node)
        for nxt in sorted(g[node]):
            if state.get(nxt) == "open":
                cycles.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = "done"

    for node in sorted(g):
        if node not in state:
            visit(node)
    # A package's __init__ importing its own modules is not a cycle of the design.
    cycles = [c for c in cycles if not any(a and b.startswith(a + ".") for a, b in zip(c, c[1:]))]
    assert not cycles, "\n".join(" -> ".join(c) for c in cycles)

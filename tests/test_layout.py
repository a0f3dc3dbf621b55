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


# Modules that exist only inside Blender (bpy and the modules Blender's Python adds).
BLENDER_MODULES = {"bpy", "bpy_extras", "bpy_types", "bmesh", "mathutils", "gpu", "gpu_extras", "bl_ui", "bl_operators",
                   "bl_ext", "bl_pkg", "addon_utils", "aud", "blf", "bgl", "idprop", "imbuf", "freestyle",
                   "rna_prop_ui", "_bpy"}


def top_level_imports(path: Path) -> set[str]:
    """The top-level names of every absolute import in a file (those inside functions too), and the
    module names given to importlib.import_module / __import__ as literal strings."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            found.add(node.module.split(".")[0])
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], (ast.Constant, ast.JoinedStr)):
            name = ast.unparse(node.func)
            if name in ("importlib.import_module", "import_module", "__import__"):
                first = node.args[0]
                text = first.value if isinstance(first, ast.Constant) else "".join(
                    v.value for v in first.values if isinstance(v, ast.Constant))
                found.add(str(text).split(".")[0] or "<dynamic>")
    return found


def test_the_core_never_imports_blender():
    """hypergs_blender/ runs without Blender (the command line, training, benchmarks, a child process
    reading a USD file): no module of it imports bpy or another of Blender's modules, or reaches the
    installed extension (bl_ext) through importlib. Headless Blender lives in tools/ and tests/."""
    wrong = {str(path.relative_to(ROOT)): sorted(top_level_imports(path) & BLENDER_MODULES)
             for path in sorted((ROOT / "hypergs_blender").rglob("*.py"))}
    wrong = {path: names for path, names in wrong.items() if names}
    assert not wrong, wrong
    # The check sees imports inside functions and through importlib (tools/ may drive Blender):
    assert {"bpy", "bl_ext"} <= top_level_imports(ROOT / "tools" / "blender_headless.py")


def test_tests_share_helpers_not_test_files():
    """A test file imports helpers (conftest.py, blender_session.py, tools/), never another test file."""
    wrong = {path.name: sorted(name for name in top_level_imports(path) if name.startswith("test_"))
             for path in sorted((ROOT / "tests").glob("*.py"))}
    wrong = {path: names for path, names in wrong.items() if names}
    assert not wrong, wrong

"""Static checks of the package's layout: layering, private names across modules, function-level imports.

Used by ``tests/test_layout.py``; ``python tests/layout_check.py [PACKAGE_DIR]`` prints the counts (the redesign
issue compares them before and after).
"""

import ast
import sys
from pathlib import Path

#: Layers from the bottom up; a module may import from its own layer and the ones below. Modules at the top of the
#: package (errors, settings, records) are the base every layer may use.
LAYERS = ("base", "runtime", "io", "geometry", "matching", "products", "sample", "scale", "cli")
BASE = {"errors", "settings", "records", "__init__", "__main__"}


def layer_of(module):
    """Layer of a dotted module name inside the package (``riverbed_cli.io.lidar`` -> ``io``)."""
    parts = module.split(".")[1:]
    if not parts or parts[0] in BASE:
        return "base"
    return parts[0]


def module_name(path, root):
    rel = path.relative_to(root.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def resolve(node, module, is_package):
    """The absolute module an ``ImportFrom`` names (None for third-party)."""
    if node.level == 0:
        return node.module if node.module and node.module.split(".")[0] == module.split(".")[0] else None
    base = module.split(".")
    if not is_package:
        base = base[:-1]
    base = base[:len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def scan(root):
    """Per-module findings: lines, higher-layer imports, private names imported, function-level imports."""
    root = Path(root)
    out = []
    for path in sorted(root.rglob("*.py")):
        mod = module_name(path, root)
        tree = ast.parse(path.read_text())
        lines = len(path.read_text().splitlines())
        higher, private, local = [], [], []
        func_nodes = set()
        for fn in ast.walk(tree):
            if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for n in ast.walk(fn):
                    if isinstance(n, (ast.Import, ast.ImportFrom)):
                        func_nodes.add(id(n))
        for n in ast.walk(tree):
            if not isinstance(n, (ast.Import, ast.ImportFrom)):
                continue
            targets = []
            if isinstance(n, ast.ImportFrom):
                target = resolve(n, mod, path.name == "__init__.py")
                if target:
                    targets.append(target)
                    for a in n.names:
                        if a.name.startswith("_") and not a.name.startswith("__"):
                            private.append(f"{target}.{a.name}")
            else:
                targets += [a.name for a in n.names if a.name.split(".")[0] == mod.split(".")[0]]
            for t in targets:
                me, it = layer_of(mod), layer_of(t)
                if mod.split(".")[-1] == "__main__":
                    continue  # an entry point sits above everything
                if LAYERS.index(it) > LAYERS.index(me):
                    higher.append(t)
            if id(n) in func_nodes:
                local.append(f"{mod}:{n.lineno}")
        out.append({"module": mod, "lines": lines, "higher": higher, "private": private, "local": local})
    return out


def summary(root):
    rows = scan(root)
    return {
        "modules": len(rows),
        "over_600_lines": [(r["module"], r["lines"]) for r in rows if r["lines"] > 600],
        "private_imports": [(r["module"], p) for r in rows for p in r["private"]],
        "higher_layer_imports": [(r["module"], h) for r in rows for h in r["higher"]],
        "function_level_imports": [loc for r in rows for loc in r["local"]],
    }


if __name__ == "__main__":
    root = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parents[1] / "riverbed_cli")
    s = summary(root)
    for k, v in s.items():
        print(f"{k}: {v if isinstance(v, int) else len(v)}")
        if not isinstance(v, int) and "-v" in sys.argv:
            for item in v:
                print("   ", item)

"""Figures of the code's shape (issue 28's before/after table): lines of the big modules, the
largest class, imports inside functions, import cycles and upward imports between the layers,
long functions and wide signatures, the places that open a config file.

    .venv/bin/python benchmarks/architecture_metrics.py [--src src/pmctl] [--json]

Static: it parses the sources with ``ast`` and imports nothing of pmctl.
"""

from __future__ import annotations

import argparse
import ast
import json
import sys
from pathlib import Path

LAYERS = ["core", "hal", "motion", "task", "tools", "interfaces"]   # low -> high


def module_name(root: Path, path: Path) -> str:
    rel = path.relative_to(root.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def layer(mod: str) -> str | None:
    parts = mod.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else None


def resolve(mod: str, is_pkg: bool, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = mod.split(".")
    if not is_pkg:
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def analyse(root: Path) -> dict:
    files = sorted(p for p in root.rglob("*.py"))
    mods = {module_name(root, p): p for p in files}
    edges: dict[str, set] = {m: set() for m in mods}
    inner = total = inner_own = 0
    long_funcs, wide_funcs, classes, config_opens = [], [], [], []
    for mod, path in mods.items():
        tree = ast.parse(path.read_text(), str(path))
        is_pkg = path.name == "__init__.py"
        func_stack = []

        def visit(node, in_func):
            nonlocal inner, total, inner_own
            for child in ast.iter_child_nodes(node):
                if isinstance(child, (ast.Import, ast.ImportFrom)):
                    if isinstance(child, ast.Import):
                        targets = [a.name for a in child.names]
                    else:
                        base = resolve(mod, is_pkg, child)
                        targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in child.names]
                    for t in targets:
                        total += 1
                        own = t.startswith("pmctl")
                        if in_func:
                            inner += 1
                            inner_own += own
                        if own:
                            while t and t not in mods:
                                t = t.rsplit(".", 1)[0] if "." in t else ""
                            if t and t != mod:
                                edges[mod].add(t)
                if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    n = (child.end_lineno or child.lineno) - child.lineno + 1
                    a = child.args
                    nparams = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) + bool(a.vararg) + bool(a.kwarg)
                    if a.args and a.args[0].arg in ("self", "cls"):
                        nparams -= 1
                    name = f"{mod}:{child.name}"
                    if n > 80:
                        long_funcs.append((name, n))
                    if nparams >= 10:
                        wide_funcs.append((name, nparams))
                    visit(child, True)
                elif isinstance(child, ast.ClassDef):
                    n = (child.end_lineno or child.lineno) - child.lineno + 1
                    meths = sum(isinstance(c, (ast.FunctionDef, ast.AsyncFunctionDef)) for c in child.body)
                    classes.append((f"{mod}:{child.name}", n, meths))
                    visit(child, in_func)
                else:
                    visit(child, in_func)

        visit(tree, False)
        src = path.read_text()
        if ("tomllib" in src or "strict_toml" in src) and ("open(" in src or "read_text" in src or "load(" in src):
            config_opens.append(mod)

    # cycles: strongly connected components of the module graph (Tarjan)
    index, low, stack, on, sccs, counter = {}, {}, [], set(), [], [0]
    sys.setrecursionlimit(10000)

    def strong(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                sccs.append(sorted(comp))

    for v in edges:
        if v not in index:
            strong(v)
    upward = sorted({(a, b) for a, bs in edges.items() for b in bs
                     if layer(a) and layer(b) and LAYERS.index(layer(b)) > LAYERS.index(layer(a))})
    lines = {m: len(p.read_text().splitlines()) for m, p in mods.items()}
    classes.sort(key=lambda c: -c[1])
    return {
        "modules": len(mods),
        "lines": sum(lines.values()),
        "biggest_modules": sorted(lines.items(), key=lambda kv: -kv[1])[:8],
        "largest_classes": classes[:5],
        "imports": total, "imports_in_functions": inner, "own_imports_in_functions": inner_own,
        "cycles": sccs, "upward_imports": upward,
        "functions_over_80_lines": sorted(long_funcs, key=lambda f: -f[1]),
        "functions_with_10_or_more_params": sorted(wide_funcs, key=lambda f: -f[1]),
        "modules_reading_toml": sorted(config_opens),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--src", default=str(Path(__file__).resolve().parents[1] / "src" / "pmctl"))
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    r = analyse(Path(a.src))
    if a.json:
        print(json.dumps(r, indent=1))
        return
    print(f"modules {r['modules']}, lines {r['lines']}")
    print("biggest modules: " + ", ".join(f"{m.split('.', 1)[1]} {n}" for m, n in r["biggest_modules"]))
    print("largest classes: " + ", ".join(f"{c.split('.', 1)[1]} {n} lines {k} methods" for c, n, k in r["largest_classes"]))
    print(f"imports {r['imports']}, inside functions {r['imports_in_functions']} "
          f"({100 * r['imports_in_functions'] / max(1, r['imports']):.0f} %), of pmctl's own {r['own_imports_in_functions']}")
    print(f"import cycles {len(r['cycles'])}:")
    for c in r["cycles"]:
        print("   " + " <-> ".join(x.split(".", 1)[1] for x in c))
    print(f"upward imports {len(r['upward_imports'])}:")
    for a_, b in r["upward_imports"]:
        print(f"   {a_.split('.', 1)[1]} -> {b.split('.', 1)[1]}")
    print(f"functions over 80 lines {len(r['functions_over_80_lines'])}: "
          + ", ".join(f"{f.split('.', 1)[1]} {n}" for f, n in r["functions_over_80_lines"][:10]))
    print(f"functions with >= 10 parameters {len(r['functions_with_10_or_more_params'])}: "
          + ", ".join(f"{f.split('.', 1)[1]} {n}" for f, n in r["functions_with_10_or_more_params"][:10]))
    print(f"modules that read TOML {len(r['modules_reading_toml'])}: " + ", ".join(m.split('.', 1)[1] for m in r["modules_reading_toml"]))


if __name__ == "__main__":
    main()

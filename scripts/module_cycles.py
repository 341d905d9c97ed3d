#!/usr/bin/env python3
"""Fails when a crate of the workspace has a cycle between its modules.

    python3 scripts/module_cycles.py [crate_src_dir ...]     (default: every crate's src/)

Each module (a file `a.rs` or a directory `a/` with `mod.rs`) is a node; module A depends on
module B when code in A names `crate::B` (or `super::B` from a sibling, or `crate::p::B` for a
sibling under parent p). Siblings are compared at every level: the crate's top-level modules,
then the children of each directory module. References from a module to its own ancestors are
ignored (a child may use its parent's items); comments and doc comments are skipped, test code
is not. Prints every strongly connected component of more than one module with one edge of
each dependency (file:line) and exits 1, or prints the number of modules checked.
"""

import re
import sys
from pathlib import Path

PATH_RE = re.compile(r"\b(crate|super)((?:::[A-Za-z_][A-Za-z0-9_]*)+)")
USE_GROUP_RE = re.compile(r"\buse\s+(crate|super)((?:::[A-Za-z_][A-Za-z0-9_]*)*)::\{([^;]*)\}", re.S)


def module_path(src: Path, f: Path) -> tuple:
    """The module path of file `f` under crate root `src` (() for lib.rs/main.rs)."""
    rel = f.relative_to(src).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] in ("mod", "lib", "main"):
        parts = parts[:-1]
    return tuple(parts)


def strip_comments(text: str) -> list:
    """The file's lines with `//` comments and `#[cfg(test)]` items blanked (line numbers
    kept): test code may use any module, it does not shape the crate."""
    out = []
    for line in text.splitlines():
        i = line.find("//")
        out.append(line if i < 0 else line[:i])
    n = 0
    while n < len(out):
        if out[n].strip() != "#[cfg(test)]":
            n += 1
            continue
        # Blank the attribute and the item after it: to its `;` or its matching `}`.
        depth, opened, k = 0, False, n
        while k < len(out):
            line = out[k]
            depth += line.count("{") - line.count("}")
            opened = opened or "{" in line
            out[k] = ""
            k += 1
            if (opened and depth <= 0) or (not opened and line.rstrip().endswith(";")):
                break
        n = k
    return out


def test_only_files(src: Path, files: list) -> set:
    """Module paths declared `#[cfg(test)] mod x;` (their files are test code)."""
    out = set()
    for f in files:
        lines = f.read_text().splitlines()
        for i, line in enumerate(lines[:-1]):
            m = re.match(r"\s*(?:pub(?:\([^)]*\))?\s+)?mod\s+(\w+)\s*;", lines[i + 1])
            if line.strip() == "#[cfg(test)]" and m:
                out.add(module_path(src, f) + (m.group(1),))
    return out


def references(mod: tuple, text: str):
    """Yields (line number, absolute module path named) for every crate:: or super:: path."""
    lines = strip_comments(text)
    body = "\n".join(lines)
    for m in USE_GROUP_RE.finditer(body):
        line = body.count("\n", 0, m.start()) + 1
        base = resolve(mod, m.group(1), m.group(2))
        for item in re.split(r"[,\s{}]+", m.group(3)):
            name = item.split("::")[0]
            if name and name not in ("self", "*") and re.match(r"[A-Za-z_]", name):
                yield line, base + (name,) + tuple(item.split("::")[1:])
    for n, line in enumerate(lines, 1):
        for m in PATH_RE.finditer(line):
            yield n, resolve(mod, m.group(1), m.group(2))


def resolve(mod: tuple, root: str, rest: str) -> tuple:
    parts = [p for p in rest.split("::") if p]
    if root == "crate":
        return tuple(parts)
    base = list(mod[:-1]) if mod else []
    while parts and parts[0] == "super":
        parts.pop(0)
        base = base[:-1]
    return tuple(base) + tuple(parts)


def sccs(nodes, edges):
    """Tarjan's strongly connected components."""
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
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
            out.append(comp)

    sys.setrecursionlimit(10000)
    for v in nodes:
        if v not in index:
            visit(v)
    return out


def check(src: Path) -> tuple:
    files = sorted(src.rglob("*.rs"))
    tests = test_only_files(src, files)
    files = [f for f in files if not any(module_path(src, f)[: len(t)] == t for t in tests)]
    modules = {module_path(src, f) for f in files}
    # Directory modules are modules too, even when only their children are files.
    for m in list(modules):
        for i in range(1, len(m)):
            modules.add(m[:i])
    # edges[(parent, a)][b] = "file:line" of one reference from sibling a to sibling b.
    edges = {}
    for f in files:
        mod = module_path(src, f)
        text = f.read_text()
        for n, target in references(mod, text):
            # The longest module prefix of the path (items after it are not modules).
            k = len(target)
            while k > 0 and target[:k] not in modules:
                k -= 1
            target = target[:k]
            if not target or target == mod[: len(target)]:
                continue  # the crate root or an ancestor of `mod`
            # The level where the two paths part: siblings under a common parent.
            common = 0
            while common < min(len(mod), len(target)) and mod[common] == target[common]:
                common += 1
            if common >= len(mod) or common >= len(target):
                continue  # `target` is inside `mod`
            parent, a, b = mod[:common], mod[common], target[common]
            edges.setdefault(parent, {}).setdefault(a, {}).setdefault(b, f"{f}:{n}")
    problems = []
    for parent, graph in sorted(edges.items()):
        nodes = sorted(set(graph) | {b for d in graph.values() for b in d})
        adj = {a: sorted(d) for a, d in graph.items()}
        for comp in sccs(nodes, adj):
            if len(comp) > 1:
                comp = sorted(comp)
                where = "::".join(parent) or "crate"
                lines = [f"cycle in {src} under {where}: {' <-> '.join(comp)}"]
                for a in comp:
                    for b in comp:
                        if b in graph.get(a, {}):
                            lines.append(f"  {a} -> {b}  ({graph[a][b]})")
                problems.append("\n".join(lines))
    return len(modules), problems


def main() -> int:
    root = Path(__file__).resolve().parent.parent
    dirs = [Path(d) for d in sys.argv[1:]] or sorted(
        p.parent for p in root.glob("*/Cargo.toml")
    ) + [root]
    total, problems = 0, []
    for d in dirs:
        src = d / "src" if (d / "src").is_dir() else d
        if not src.is_dir():
            continue
        n, p = check(src)
        total += n
        problems += p
    if problems:
        print("\n".join(problems))
        print(f"{len(problems)} module cycle(s)")
        return 1
    print(f"no module cycles: {total} modules in {len(dirs)} crates")
    return 0


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/env python3
"""Module import cycles inside one crate's src/ (default: daemon/src).

Every reference of a file to another module of the crate counts as an import: `crate::a::b`,
`super::x`, `self::x`, a path that starts with a top-level module (`cmd::run::Args` after
`use crate::cmd;`) and, in a module with children, a path through a child (`capball::run`).
Inline `#[cfg(test)] mod tests` blocks are left out (a test module uses its parent by
design). Prints every pair of modules importing each other and every larger cycle; exits 1
when there is any.

    python3 .ci/module_cycles.py [daemon/src]
"""
import re
import sys
from pathlib import Path

root = Path(sys.argv[1] if len(sys.argv) > 1 else "daemon/src")


def module_of(path: Path) -> tuple:
    rel = path.relative_to(root).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] in ("mod", "lib", "main"):
        parts = parts[:-1]
    return tuple(parts)


files = {module_of(p): p for p in root.rglob("*.rs")}
modules = set(files)
top = {m[0] for m in modules if len(m) == 1}


def code_only(text: str) -> str:
    """The text with comments, string and char literals blanked (their quotes kept)."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            i = n if j < 0 else j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            i = n if j < 0 else j + 2
        elif c == "r" and re.match(r'r#*"', text[i:]) and not (i and (text[i - 1].isalnum() or text[i - 1] == "_")):
            hashes = re.match(r'r(#*)"', text[i:]).group(1)
            j = text.find('"' + hashes, i + 2 + len(hashes))
            out.append('""')
            i = n if j < 0 else j + 1 + len(hashes)
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            out.append('""')
            i = j + 1
        elif c == "'":
            m = re.match(r"'(\\.[^']*|[^'\\])'", text[i:])
            if m:
                out.append("' '")
                i += m.end()
            else:
                out.append(c)
                i += 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def strip(text: str) -> str:
    # Comments, strings and inline test modules are not imports.
    text = code_only(text)
    m = re.search(r"#\[cfg\(test\)\]\s*mod\s+\w+\s*\{", text)
    if m:
        depth, i = 0, m.end() - 1
        while i < len(text):
            depth += {"{": 1, "}": -1}.get(text[i], 0)
            if depth == 0:
                break
            i += 1
        text = text[: m.start()] + text[i + 1 :]
    return text


def resolve(start: tuple, segs: list) -> tuple:
    """The longest module prefix of a path, from module `start`."""
    cur = start
    best = None
    for s in segs:
        if s == "super":
            cur = cur[:-1]
            best = cur
            continue
        if s == "self":
            best = cur
            continue
        nxt = cur + (s,)
        if nxt in modules:
            cur = nxt
            best = cur
        else:
            break
    return best


edges = {}
for mod, path in files.items():
    text = strip(path.read_text())
    # `prefix::{a, b::c, self}` groups, one level deep.
    for g in re.finditer(r"((?:\w+::)+)\{([^{}]*)\}", text):
        for item in g.group(2).split(","):
            item = item.strip().split(" as ")[0].strip()
            if item and item != "self":
                text += f"\n{g.group(1)}{item}"
    deps = set()
    children = {m[-1] for m in modules if m[:-1] == mod and len(m) == len(mod) + 1}
    for m in re.finditer(r"\b(\w+)((?:::\w+)+)", text):
        head = m.group(1)
        segs = m.group(2).split("::")[1:]
        if head == "crate":
            target = resolve((), segs)
        elif head in ("super", "self"):
            target = resolve(mod, [head] + segs)
        elif head in children:
            target = resolve(mod, [head] + segs)
        elif head in top and head not in ("main",):
            target = resolve((), [head] + segs)
        else:
            continue
        if target is not None and target != mod and target != ():
            deps.add(target)
    edges[mod] = deps


def name(m):
    return "crate::" + "::".join(m) if m else "crate"


bad = 0
for a in sorted(edges):
    for b in sorted(edges[a]):
        if a < b and a in edges.get(b, ()):
            print(f"mutual: {name(a)} <-> {name(b)}")
            bad += 1

# Larger cycles: strongly connected components (Tarjan).
index, low, stack, on, sccs, counter = {}, {}, [], set(), [], [0]


def visit(v):
    index[v] = low[v] = counter[0]
    counter[0] += 1
    stack.append(v)
    on.add(v)
    for w in edges.get(v, ()):
        if w not in edges:
            continue
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
        sccs.append(comp)


sys.setrecursionlimit(10000)
for v in sorted(edges):
    if v not in index:
        visit(v)
for comp in sccs:
    if len(comp) > 2:
        print("cycle: " + ", ".join(name(m) for m in sorted(comp)))
        bad += 1
print(f"{len(edges)} modules in {root}, {sum(len(d) for d in edges.values())} imports, {bad} cycle(s)")
sys.exit(1 if bad else 0)

"""The shape of the code (issue 14, docs/architecture.md), checked from the source text:
layers and the direction of imports, no cycles, one name per kernel through every layer
(shaders/<group>/K.wgsl, kernels/<group>.py class, reference/<group>.py::K twin,
tests/kernels/test_<group>.py::test_K), WGSL as the source of workgroup sizes, readable sizes.

Every check reads files only: no device, no imports of the package beyond the WGSL reflection."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PKG = ROOT / "tsplus_wgpu"

MAX_FILE_LINES = 500
MAX_FUNCTION_LINES = 80
MAX_README_LINES = 260

#: what each part of the package may import (beside itself). Parts are the first component
#: under tsplus_wgpu/ ("types", "gpu", ...); "reference" may import single modules only.
ALLOWED = {
    "types": set(),
    "errors": set(),
    "sh": {"types"},
    "gpu": {"types", "errors"},
    "reference": {"types", "sh", "gpu.wgsl", "io.metrics"},
    "kernels": {"gpu", "types", "sh"},
    "render": {"gpu", "kernels", "types", "sh", "errors"},
    "io": {"types", "sh", "errors", "gpu", "render", "data"},
    "data": {"types", "sh", "errors", "io"},
    "train": {"types", "sh", "errors", "gpu", "kernels", "render", "data", "io"},
    "apps": {"types", "sh", "errors", "gpu", "kernels", "render", "data", "io", "train", "__init__"},
    "bench": {"types", "sh", "errors", "gpu", "kernels", "render", "data", "io", "train", "apps", "__init__"},
    "cli": None,            # the top of the stack: anything
    "__init__": {"types", "sh", "errors", "gpu", "kernels", "render", "data", "io", "train", "apps", "reference"},
}


def _modules():
    out = {}
    for p in sorted(PKG.rglob("*.py")):
        rel = p.relative_to(PKG).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(["tsplus_wgpu"] + parts)] = p
    return out


MODULES = _modules()


def _imports(path, modname):
    """Every tsplus_wgpu module imported by ``path`` (module level and inside functions)."""
    tree = ast.parse(path.read_text())
    is_pkg = path.name == "__init__.py"
    base = modname.split(".") if is_pkg else modname.split(".")[:-1]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                root = base[: len(base) - node.level + 1]
                mod = ".".join(root + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            subs = [f"{mod}.{a.name}" for a in node.names]
            # ``from pkg import module`` imports the module (and runs pkg/__init__ only on first import)
            names = subs + ([mod] if any(s not in MODULES for s in subs) else [])
        else:
            continue
        for n in names:
            while n and n not in MODULES:
                n = n.rpartition(".")[0]
            if n.startswith("tsplus_wgpu") and n != modname:
                found.add(n)
    return found


GRAPH = {m: _imports(p, m) for m, p in MODULES.items()}


def _part(mod):
    parts = mod.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def test_import_direction():
    bad = []
    for mod, deps in GRAPH.items():
        allowed = ALLOWED.get(_part(mod))
        if allowed is None and _part(mod) in ALLOWED:
            continue
        for dep in deps:
            part = _part(dep)
            if part == _part(mod) or dep == "tsplus_wgpu" and _part(mod) != "reference":
                continue
            sub = ".".join(dep.split(".")[1:3])
            if allowed is None or (part not in allowed and sub not in allowed):
                bad.append(f"{mod} imports {dep}")
    assert not bad, "imports against the layering of docs/architecture.md:\n" + "\n".join(sorted(bad))


def test_no_import_cycles():
    index, low, stack, on, cycles, counter = {}, {}, [], set(), [], [0]

    def strong(v):          # Tarjan's strongly connected components
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(GRAPH.get(v, ())):
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
            # a package importing its own submodules (re-exports) is not a cycle
            comp = [c for c in comp if not any(o != c and o.startswith(c + ".") for o in comp)]
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in sorted(GRAPH):
        if v not in index:
            strong(v)
    assert not cycles, "import cycles (module-level or inside functions):\n" + "\n".join(map(str, cycles))


def _python_files():
    files = sorted(PKG.rglob("*.py")) + sorted((ROOT / "viewer").rglob("*.py"))
    return [p for p in files if "__pycache__" not in p.parts]


def test_file_and_function_sizes():
    bad = []
    for p in _python_files():
        text = p.read_text()
        n = text.count("\n")
        if n > MAX_FILE_LINES:
            bad.append(f"{p.relative_to(ROOT)}: {n} lines")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = node.end_lineno - node.lineno + 1
                if length > MAX_FUNCTION_LINES:
                    bad.append(f"{p.relative_to(ROOT)}:{node.lineno} {node.name}: {length} lines")
    assert not bad, f"over {MAX_FILE_LINES} lines per file / {MAX_FUNCTION_LINES} per function:\n" + "\n".join(bad)


def test_readme_is_short():
    n = (ROOT / "README.md").read_text().count("\n")
    assert n <= MAX_README_LINES, f"README.md has {n} lines; the long material belongs in docs/"


def _camel(name):
    return "".join(w.capitalize() for w in name.split("_"))


def _defs(path):
    """{class name: stage string or None} and the set of function names at module level."""
    classes, funcs = {}, set()
    if not path.is_file():
        return classes, funcs
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.ClassDef):
            stage = None
            for item in node.body:
                if (isinstance(item, ast.Assign) and any(getattr(t, "id", "") == "stage" for t in item.targets)
                        and isinstance(item.value, ast.Constant)):
                    stage = item.value.value
            classes[node.name] = stage
        elif isinstance(node, ast.FunctionDef):
            funcs.add(node.name)
        elif isinstance(node, ast.Assign):       # e.g. ``rasterize_ids = ...`` aliases
            funcs.update(t.id for t in node.targets if isinstance(t, ast.Name))
    return classes, funcs


def _kernels():
    shaders = ROOT / "shaders"
    return sorted((p.parent.name, p.stem) for p in shaders.glob("*/*.wgsl") if p.parent.name not in ("common", "mesh",
                                                                                                         "viewer"))


KERNELS = _kernels()


@pytest.mark.parametrize("group,kernel", KERNELS, ids=[k for _, k in KERNELS])
def test_one_name_per_kernel(group, kernel):
    classes, _ = _defs(PKG / "kernels" / f"{group}.py")
    _, twins = _defs(PKG / "reference" / f"{group}.py")
    _, tests = _defs(ROOT / "tests" / "kernels" / f"test_{group}.py")
    missing = []
    if classes.get(_camel(kernel)) != kernel:
        missing.append(f"class {_camel(kernel)} with stage = {kernel!r} in tsplus_wgpu/kernels/{group}.py")
    if kernel not in twins:
        missing.append(f"twin {kernel}() in tsplus_wgpu/reference/{group}.py")
    if f"test_{kernel}" not in tests:
        missing.append(f"test_{kernel} in tests/kernels/test_{group}.py")
    assert not missing, f"shaders/{group}/{kernel}.wgsl lacks: " + "; ".join(missing)


def test_every_stage_class_names_an_existing_kernel():
    names = {k for _, k in KERNELS}
    bad = []
    for p in sorted((PKG / "kernels").glob("*.py")):
        for cls, stage in _defs(p)[0].items():
            if stage is not None and stage not in names:
                bad.append(f"{p.name}: {cls}.stage = {stage!r}")
            elif stage is not None and (p.stem, stage) not in KERNELS:
                bad.append(f"{p.name}: {cls}.stage = {stage!r} lives in another group")
    assert not bad, "\n".join(bad)


def test_workgroup_sizes_are_read_from_wgsl():
    """No host code types a workgroup size: dispatch counts come from the shader's
    ``@workgroup_size`` (``Stage.groups``) or its constants (``Stage.const``)."""
    pat = re.compile(r"\bgroups\([^()]*(?:\([^()]*\)[^()]*)*,\s*\d+\s*\)")
    bad = []
    for part in ("kernels", "render", "train"):
        for p in sorted((PKG / part).rglob("*.py")):
            for i, line in enumerate(p.read_text().splitlines(), 1):
                if pat.search(line):
                    bad.append(f"{p.relative_to(ROOT)}:{i}: {line.strip()}")
    assert not bad, "literal per-workgroup counts:\n" + "\n".join(bad)


def test_no_private_access_from_outside():
    """``x._name`` only on ``self``/``cls`` (or a module's own names): no reaching into another
    object's or module's internals."""
    pat = re.compile(r"(?<![\w.])(?!self\b|cls\b|super\(\))([A-Za-z]\w*)\._[a-z]\w*")
    bad = []
    for p in _python_files():
        for i, line in enumerate(p.read_text().splitlines(), 1):
            code = line.split("#", 1)[0]
            for m in pat.finditer(code):
                if m.group(1) in ("os", "sys", "np", "wgpu"):     # e.g. sys._getframe: not ours
                    continue
                bad.append(f"{p.relative_to(ROOT)}:{i}: {m.group(0)}")
    assert not bad, "private attributes reached from outside:\n" + "\n".join(bad)


def test_reference_namespace_names_its_modules():
    """``reference.<group>`` is the module whatever was imported first (no function shadows a
    module of the same name), so ``reference.backward.rasterize_backward`` always works."""
    import importlib
    import pkgutil

    import tsplus_wgpu.reference as reference
    names = [m.name for m in pkgutil.iter_modules(reference.__path__)]
    for name in names:
        importlib.import_module(f"tsplus_wgpu.reference.{name}")
    bad = [n for n in names if getattr(reference, n) is not importlib.import_module(f"tsplus_wgpu.reference.{n}")]
    assert not bad, f"reference.<name> is not the module for {bad}"


def test_viewer_uses_the_public_api_only():
    """The live viewer imports names from ``tsplus_wgpu`` itself, never from its modules."""
    bad = []
    for p in sorted((ROOT / "viewer").glob("*.py")):
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ImportFrom) and not node.level and (node.module or "").startswith("tsplus_wgpu."):
                bad.append(f"{p.name}:{node.lineno} from {node.module} import ...")
            elif isinstance(node, ast.Import):
                bad += [f"{p.name}:{node.lineno} import {a.name}" for a in node.names if a.name.startswith("tsplus_wgpu.")]
    assert not bad, "\n".join(bad)


def test_pycolmap_is_imported_in_one_place():
    """pycolmap's first import installs COLMAP's crash-report handler for SIGTERM; only
    ``data/long_calls.import_pycolmap`` puts the command's own handler back, so no other module
    may import it (a new ``import pycolmap`` elsewhere would bring the crash report back)."""
    import re
    found = [str(p.relative_to(ROOT)) for p in sorted(list(PKG.rglob("*.py")) + list((ROOT / "viewer").rglob("*.py")))
             if re.search(r"^\s*(import pycolmap|from pycolmap import)", p.read_text(), re.M)]
    assert found == ["tsplus_wgpu/data/long_calls.py"], found

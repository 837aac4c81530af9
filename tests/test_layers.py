"""The import direction of scapo's stages: a module imports only from its own stage or lower ones
(also inside functions), so the import graph between stages has no cycles."""

import ast
from pathlib import Path

import scapo

#: Stages bottom-up; a module belongs to the stage of its longest listed prefix.
STAGES = [
    ("scapo", "scapo.errors", "scapo.registry", "scapo.files", "scapo.report", "scapo.provenance"),
    ("scapo.ops",),
    ("scapo.sim",),
    ("scapo.data",),
    ("scapo.eval",),
    ("scapo.twin",),
    ("scapo.nn",),
    ("scapo.losses",),
    ("scapo.engine",),
    ("scapo.models",),
    ("scapo.steps",),
    ("scapo.methods",),
    ("scapo.bench",),
    ("scapo.cli",),
]


def stage_of(module: str) -> int:
    best, stage = -1, None
    for i, prefixes in enumerate(STAGES):
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and len(p) > best:
                best, stage = len(p), i
    assert stage is not None, f"{module} is in no stage; add it to STAGES"
    return stage


def imports() -> dict[str, set[str]]:
    root = Path(scapo.__file__).parent
    out = {}
    for path in root.rglob("*.py"):
        parts = path.relative_to(root.parent).with_suffix("").parts
        mod = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 and node.module.startswith("scapo"):
                deps.add(node.module)
                deps.update(f"{node.module}.{a.name}" for a in node.names
                            if (root.parent / node.module.replace(".", "/") / a.name).exists()
                            or (root.parent / (node.module.replace(".", "/") + "/" + a.name + ".py")).exists())
            elif isinstance(node, ast.Import):
                deps.update(a.name for a in node.names if a.name.startswith("scapo"))
        out[mod] = deps
    return out


def test_every_module_imports_only_its_own_or_lower_stages():
    graph = imports()
    assert {"scapo.ops.rigid", "scapo.methods.registry", "scapo.methods.op_align"} <= set(graph)
    upward = sorted(f"{m} (stage {stage_of(m)}) imports {d} (stage {stage_of(d)})"
                    for m, deps in graph.items() for d in deps if stage_of(d) > stage_of(m))
    assert not upward, "imports that point up a stage:\n" + "\n".join(upward)


def test_shared_geometry_lives_below_its_users():
    graph = imports()
    for m, deps in graph.items():
        if m.startswith("scapo.ops"):
            assert all(d.startswith(("scapo.ops", "scapo.errors")) for d in deps), (m, deps)
    users = {m for m, deps in graph.items() if any(d.startswith("scapo.ops") for d in deps)}
    for stage in ("scapo.sim", "scapo.losses", "scapo.models", "scapo.methods", "scapo.eval"):
        assert any(u.startswith(stage) for u in users), f"{stage} does not use scapo.ops"


def test_stage_packages_form_no_cycle():
    graph = imports()
    pkg = {}
    for m, deps in graph.items():
        a = ".".join(m.split(".")[:2])
        pkg.setdefault(a, set()).update(".".join(d.split(".")[:2]) for d in deps if ".".join(d.split(".")[:2]) != a)
    seen, stack = set(), []

    def visit(n):
        assert n not in stack, "import cycle: " + " -> ".join([*stack[stack.index(n):], n])
        if n in seen:
            return
        stack.append(n)
        for d in pkg.get(n, ()):
            if d != "scapo":
                visit(d)
        stack.pop()
        seen.add(n)

    for n in pkg:
        visit(n)


def _from_imports() -> list[tuple[str, str, str]]:
    """(module, imported-from module, name) of every ``from scapo... import name`` in the package."""
    root = Path(scapo.__file__).parent
    out = []
    for path in root.rglob("*.py"):
        parts = path.relative_to(root.parent).with_suffix("").parts
        mod = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("scapo"):
                out += [(mod, node.module, a.name) for a in node.names]
    return out


def test_rotation_helpers_come_from_ops_only():
    helpers = {"skew", "exp_so3", "log_so3", "make_transform", "invert_transform", "invert", "rotation_from_rotvec",
               "rotation_from_6d", "gram_schmidt", "rotation_between"}
    wrong = [f"{m} imports {n} from {src}" for m, src, n in _from_imports()
             if n in helpers and not src.startswith("scapo.ops")]  # numpy ones: scapo.ops.rigid
    assert not wrong, "\n".join(wrong)


def test_only_scapos_method_module_and_the_cli_import_the_model_package():
    allowed = ("scapo.models", "scapo.methods.scapo", "scapo.cli")
    wrong = sorted({f"{m} imports {src}" for m, src, _ in _from_imports()
                    if src.startswith("scapo.models") and not m.startswith(allowed)})
    assert not wrong, "\n".join(wrong)


def test_the_layout_lists_every_package_with_its_imports():
    """The Layout block of docs/DEVELOPING.md: one line per stage package (``scapo/`` for the top-level modules,
    ``scapo/bench/`` for the top stage's modules), bottom-up, each with the packages it imports (``| a, b``), as the
    tree has them."""
    readme = (Path(scapo.__file__).parent.parent / "docs" / "DEVELOPING.md").read_text()
    block = readme.split("## Layout", 1)[1].split("```", 2)[1]
    lines = [ln for ln in block.splitlines() if ln.startswith("scapo/") and "|" in ln]
    listed = [ln.split()[0].rstrip("/").replace("/", ".") for ln in lines]
    assert listed == [s[0] for s in STAGES], ("docs/DEVELOPING.md Layout lists other packages (or another order) than "
                                              "STAGES")
    graph = imports()
    for line, stage in zip(lines, STAGES):
        i = STAGES.index(stage)
        want = {STAGES[stage_of(d)][0] for m, deps in graph.items() if stage_of(m) == i for d in deps} - {stage[0]}
        names = {w.strip() for w in line.split("|", 1)[1].split(",")} - {"-"}
        got = {"scapo" if n == "scapo" else f"scapo.{n}" for n in names}
        assert got == want, f"{stage[0]}: docs/DEVELOPING.md says it imports {sorted(got)}, the code {sorted(want)}"
    packages = {p.name for p in Path(scapo.__file__).parent.iterdir() if (p / "__init__.py").is_file()}
    assert {f"scapo.{p}" for p in packages} <= {m for s in STAGES for m in s}, "a package is in no stage"

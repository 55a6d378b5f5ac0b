"""The package's import layers and the absence of import cycles, read from the source with `ast`.

Every `import` counts, including those inside functions (lazy imports hide a dependency, they do
not remove it). A module may import from its own package or from a lower tier only; packages in
the same tier are independent of each other (teachers, terrain and bodies never import one
another). A new top-level module or package that imports from acl3d must be given a tier here.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "acl3d"

# Lowest first. "acl3d" is the package's own __init__: it registers the environments.
TIERS: tuple[tuple[str, ...], ...] = (
    ("validation", "assets", "rendering", "video", "overlay", "atomic_files"),
    ("task_space", "run_format"),
    ("curriculum_profile", "provenance"),
    ("terrain", "bodies", "teachers", "toy", "playback"),
    ("devices",),
    ("sim",),
    ("envs",),
    ("acl3d",),
    ("vec",),
    ("training",),
    ("campaign", "analysis"),
    ("cli",),
    ("__main__",),
)
TIER = {component: rank for rank, names in enumerate(TIERS) for component in names}
# Third-party packages a component may import only from this tier up: the environments stay
# Gymnasium-only (no learning library), Stable-Baselines3 enters with the vec envs.
THIRD_PARTY_FROM: dict[str, str] = {
    "stable_baselines3": "vec",
    "torch": "teachers",
    "ray": "campaign",
    "warp": "sim",
    "mujoco_warp": "sim",
}


def _modules() -> dict[str, Path]:
    modules = {}
    for path in ROOT.rglob("*.py"):
        parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        modules[".".join(parts)] = path
    return modules


MODULES = _modules()


def _third_party(path: Path) -> set[str]:
    """Top-level names of the non-acl3d packages a module imports (anywhere in it)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            found.add(node.module.split(".")[0])
    return found - {"acl3d"}


def _resolve(name: str) -> str | None:
    """The acl3d module that `name` (a module or a module.attribute) lives in, if any."""
    while name not in MODULES and "." in name:
        name = name.rsplit(".", 1)[0]
    return name if name in MODULES else None


def _imports(module: str, source: str | None = None) -> set[str]:
    """The acl3d modules that `module` imports (its own source unless `source` is given)."""
    path = MODULES[module]
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    found = set()
    tree = ast.parse(path.read_text() if source is None else source, str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            # `from acl3d import validation` imports the submodule, not the package's __init__
            targets = [
                f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names
            ]
        else:
            continue
        found |= {t for t in map(_resolve, targets) if t is not None and t != module}
    return found


GRAPH = {module: _imports(module) for module in MODULES}


def component(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def test_every_component_that_imports_acl3d_has_a_tier():
    """A leaf (a module importing nothing from acl3d) may go unlisted: anything may import it."""
    missing = sorted(
        {
            component(m)
            for m, targets in GRAPH.items()
            if component(m) not in TIER and any(component(t) != component(m) for t in targets)
        }
    )
    assert not missing, f"give these top-level modules a tier in tests/test_layering.py: {missing}"


def test_no_module_imports_a_layer_above_it_or_a_peer():
    bad = []
    for module, targets in GRAPH.items():
        for target in targets:
            own, other = component(module), component(target)
            if own != other and TIER.get(other, -1) >= TIER.get(own, -1):
                bad.append(f"{module} -> {target}")
    assert not bad, "imports against the layers:\n" + "\n".join(sorted(bad))


def test_third_party_packages_enter_at_their_layer():
    """No environment module imports Stable-Baselines3 or torch, and so on (`THIRD_PARTY_FROM`)."""
    bad = []
    for module, path in MODULES.items():
        own = TIER.get(component(module), len(TIERS))
        for package in _third_party(path) & set(THIRD_PARTY_FROM):
            lowest = THIRD_PARTY_FROM[package]
            if own < TIER[lowest] or (own == TIER[lowest] and component(module) != lowest):
                bad.append(f"{module} imports {package} (allowed from {lowest} up)")
    assert not bad, "third-party imports below their layer:\n" + "\n".join(sorted(bad))


def _code_strings(path: Path) -> list[str]:
    """The string constants of a module that are not docstrings."""
    tree = ast.parse(path.read_text())
    documented = (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)
    docstrings = {
        id(node.body[0].value)
        for node in ast.walk(tree)
        if isinstance(node, documented) and node.body and isinstance(node.body[0], ast.Expr)
    }
    return [
        node.value
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and isinstance(node.value, str)
        if id(node) not in docstrings
    ]


def test_teachers_name_no_environment():
    names = ("stump", "hexagon", "parkour", "tracks-v", "acl3d/")
    bad = [
        f"{path.name}: {text!r}"
        for path in sorted((ROOT / "teachers").glob("*.py"))
        for text in _code_strings(path)
        if any(name in text.lower() for name in names)
    ]
    assert not bad, f"environment names in teacher code: {bad}"


def _compared_strings(path: Path):
    """String constants a module compares with (==, in, ...), uses as dict keys or matches."""
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Compare):
            sides = [node.left, *node.comparators]
            items = [
                e for c in sides if isinstance(c, (ast.Tuple, ast.List, ast.Set)) for e in c.elts
            ]
            consts = [*sides, *items]
        elif isinstance(node, ast.Dict):
            consts = [k for k in node.keys if k is not None]
        elif isinstance(node, ast.MatchValue):
            consts = [node.value]
        else:
            continue
        yield from (
            (node.lineno, c.value)
            for c in consts
            if isinstance(c, ast.Constant) and isinstance(c.value, str)
        )


def test_only_teachers_test_a_teachers_name():
    """What a teacher needs elsewhere (plots, the toy, the training loop) it declares on its class;
    no module outside acl3d/teachers branches on its name."""
    from acl3d.teachers import TEACHERS

    bad = [
        f"{path.relative_to(ROOT)}:{line}: {text!r}"
        for path in sorted(ROOT.rglob("*.py"))
        if "teachers" not in path.relative_to(ROOT).parts
        for line, text in _compared_strings(path)
        if text in TEACHERS
    ]
    assert not bad, f"teacher names tested outside acl3d/teachers: {bad}"


def test_no_import_cycles():
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    cycles = []

    def visit(module: str, path: list[str]) -> None:
        state[module] = 1
        for target in sorted(GRAPH[module]):
            if state.get(target) == 1:
                cycles.append(" -> ".join(path[path.index(target) :] + [target]))
            elif target not in state:
                visit(target, path + [target])
        state[module] = 2

    for module in sorted(GRAPH):
        if module not in state:
            visit(module, [module])
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


@pytest.mark.parametrize(
    "source, expected",
    [
        ("from acl3d.envs import make", {"acl3d.envs"}),
        ("from acl3d import validation", {"acl3d.validation"}),
        ("def f():\n    from .base import Teacher", {"acl3d.teachers.base"}),
        ("import acl3d.training.workers as w", {"acl3d.training.workers"}),
        ("from . import test_sets", {"acl3d.teachers.test_sets"}),
    ],
)
def test_the_import_reader_sees_every_form(source, expected):
    assert _imports("acl3d.teachers.controller", source) == expected

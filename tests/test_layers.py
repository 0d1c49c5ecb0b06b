"""The layer rule, checked by static analysis of every import in every file of the packages.

    aibo_core    NumPy-only foundation      never imports aibo_gym, learners, experiments, aibo
    aibo_gym     the simulator              never imports learners, experiments, aibo
    learners     read logs, never envs      never imports aibo_gym, gymnasium, experiments, aibo
    experiments  above both                 never imports aibo
    aibo         the command                may import everything

Every ``import`` / ``from ... import`` statement counts wherever it stands (inside a function, under
``if TYPE_CHECKING``, in a ``try``), relative imports are resolved, and so are ``importlib.import_module``
/ ``__import__`` calls with a constant name: a lazy import cannot hide a dependency.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: package -> top-level modules it must never import
FORBIDDEN: dict[str, frozenset[str]] = {
    "aibo_core": frozenset({"aibo_gym", "learners", "experiments", "aibo"}),
    "aibo_gym": frozenset({"learners", "experiments", "aibo"}),
    "learners": frozenset({"aibo_gym", "gymnasium", "experiments", "aibo"}),
    "experiments": frozenset({"aibo"}),
}


def module_name(path: Path, root: Path) -> str:
    """Dotted name of a package file: ``learners/em/fit.py`` -> ``learners.em.fit``."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_modules(source: str, module: str, is_package: bool) -> list[tuple[int, str]]:
    """(line, absolute dotted name) of every module ``source`` imports, wherever the statement stands."""
    package = module if is_package else module.rpartition(".")[0]
    out: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            out.append((node.lineno, name))
        elif isinstance(node, ast.Call) and _is_dynamic_import(node.func) and node.args:
            arg = node.args[0]
            if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                out.append((node.lineno, arg.value))
    return out


def _is_dynamic_import(func: ast.expr) -> bool:
    """``importlib.import_module(...)``, ``import_module(...)`` or ``__import__(...)``."""
    if isinstance(func, ast.Attribute):
        return func.attr == "import_module"
    return isinstance(func, ast.Name) and func.id in ("import_module", "__import__")


def violations(root: Path, forbidden: dict[str, frozenset[str]]) -> list[str]:
    """``file:line: package imports name`` for every forbidden import under ``root``."""
    found = []
    for package, banned in forbidden.items():
        for path in sorted((root / package).rglob("*.py")):
            module = module_name(path, root)
            for line, name in imported_modules(path.read_text(encoding="utf-8"), module, path.name == "__init__.py"):
                if name.split(".")[0] in banned:
                    found.append(f"{path.relative_to(root)}:{line}: {package} imports {name}")
    return found


def test_every_package_keeps_to_its_layer():
    for package in FORBIDDEN:
        assert (ROOT / package / "__init__.py").exists(), package
    assert violations(ROOT, FORBIDDEN) == []


@pytest.mark.parametrize("statement, caught", [
    ("import aibo_gym", True),
    ("def f():\n    from aibo_gym.envs import AiboBeaconsEnv\n", True),  # a lazy import
    ("if TYPE_CHECKING:\n    import gymnasium as gym\n", True),
    ("try:\n    from experiments import run\nexcept ImportError:\n    pass\n", True),
    ("import importlib\nm = importlib.import_module('aibo.cli')\n", True),
    ("from .inference import batch\nimport numpy\nfrom aibo_core import geometry\n", False),
    ("import gymnasium_robotics\n", False),  # another top-level name that merely starts alike
])
def test_the_check_sees_lazy_and_hidden_imports(tmp_path, statement, caught):
    pkg = tmp_path / "learners" / "em"
    pkg.mkdir(parents=True)
    (tmp_path / "learners" / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "mod.py").write_text(statement)
    found = violations(tmp_path, {"learners": FORBIDDEN["learners"]})
    assert bool(found) == caught, found
    if caught:
        assert found[0].startswith(str(Path("learners/em/mod.py")))


def test_relative_imports_resolve_to_their_package():
    names = [n for _, n in imported_modules("from . import a\nfrom ..model import b\n", "learners.em.fit", False)]
    assert names == ["learners.em", "learners.model"]
    names = [n for _, n in imported_modules("from .kernels import c\n", "learners.inference", True)]
    assert names == ["learners.inference.kernels"]


def import_cycles(root: Path, package: str) -> list[list[str]]:
    """The import cycles among the modules of ``package`` (every import statement, lazy ones included): each
    as the list of modules around it. A lazy import that only breaks a cycle at import time still ties the two
    modules; the options of a fit, its E-step and its loop must read one way."""
    graph: dict[str, set[str]] = {}
    for path in sorted((root / package).rglob("*.py")):
        module = module_name(path, root)
        names = {n for _, n in imported_modules(path.read_text(encoding="utf-8"), module, path.name == "__init__.py")}
        graph[module] = names
    modules = set(graph)
    # an import of a name inside a module (``from learners.em.fit import e_step``) resolves to that module
    edges = {m: {n for n in names if n in modules and n != m and not m.startswith(n + ".")} for m, names in graph.items()}
    cycles, state = [], {}

    def visit(m: str, stack: list[str]) -> None:
        state[m] = "open"
        for n in sorted(edges[m]):
            if state.get(n) == "open":
                cycles.append(stack[stack.index(n):] + [n])
            elif n not in state:
                visit(n, stack + [n])
        state[m] = "done"

    for m in sorted(edges):
        if m not in state:
            visit(m, [m])
    return cycles


def test_the_fit_modules_import_one_way():
    """``learners.em.options`` (EMOptions and its defaults) and ``learners.em.estep`` are leaves the loop, the
    acceleration, the M-step and the search read; no module of the EM package imports one that imports it back."""
    cycles = [c for c in import_cycles(ROOT, "learners") if any(m.startswith("learners.em.") for m in c)]
    assert cycles == []
    options = {n for _, n in imported_modules((ROOT / "learners/em/options.py").read_text(), "learners.em.options", False)}
    assert not [n for n in options if n.startswith("learners")]


def test_the_cycle_check_finds_a_lazy_cycle(tmp_path):
    pkg = tmp_path / "learners" / "em"
    pkg.mkdir(parents=True)
    (tmp_path / "learners" / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from learners.em.b import x\n")
    (pkg / "b.py").write_text("def f():\n    from learners.em.a import y\n")
    (pkg / "c.py").write_text("from learners.em import a\n")
    assert import_cycles(tmp_path, "learners") == [["learners.em.a", "learners.em.b", "learners.em.a"]]


def _imports_of(package: str) -> list[tuple[str, str]]:
    """(module, imported name) of every import statement in ``package`` (lazy ones included)."""
    found = []
    for path in sorted((ROOT / Path(*package.split("."))).rglob("*.py")):
        module = module_name(path, ROOT)
        found += [(module, n) for _, n in imported_modules(path.read_text(encoding="utf-8"), module,
                                                           path.name == "__init__.py")]
    return found


def _inside(name: str, package: str) -> bool:
    return name == package or name.startswith(package + ".")


def test_the_model_and_inference_import_only_the_arrays_they_exchange():
    """``learners.model`` writes the lowered arrays and reads posteriors, ``learners.inference`` the other way round:
    both import ``learners.arrays`` and neither imports the other (the components once imported the E-step's types
    from inference, and inference the model)."""
    model = [(m, n) for m, n in _imports_of("learners.model") if _inside(n, "learners.inference")]
    inference = [(m, n) for m, n in _imports_of("learners.inference") if _inside(n, "learners.model")]
    arrays = [(m, n) for m, n in _imports_of("learners.arrays") if _inside(n, "learners") and not _inside(n, "learners.arrays")]
    assert (model, inference, arrays) == ([], [], [])

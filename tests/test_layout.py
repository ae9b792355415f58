"""The house rules, checked: which folder may import what, and what stays out of the light entry points."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _imports(path: Path, top_level_only: bool = False) -> list[tuple[str, list[str]]]:
    """Return (module, names) of every import in a file (or only those at module level)."""
    tree = ast.parse(path.read_text())
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    out = []
    for node in nodes:
        if isinstance(node, ast.Import):
            out += [(a.name, []) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append((node.module, [a.name for a in node.names]))
    return out


def _module_path(name: str) -> Path | None:
    p = ROOT / Path(*name.split("."))
    if (p / "__init__.py").exists():
        return p / "__init__.py"
    return p.with_suffix(".py") if p.with_suffix(".py").exists() else None


def _closure(module: str) -> set[str]:
    """Every module imported at module level by ``module``, transitively, and everything it imports anywhere."""
    seen: set[str] = set()
    todo = [module]
    outside: set[str] = set()
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        path = _module_path(m)
        if path is None:
            continue
        for name, _ in _imports(path, top_level_only=(m != module)):
            outside.add(name)
            if name.split(".")[0] in ("app", "planner", "inference"):
                todo.append(name)
    return outside | seen


def _package_files(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


def _modules(folder: str) -> list[str]:
    return [
        ".".join(p.relative_to(ROOT).with_suffix("").parts)
        for p in sorted((ROOT / folder).glob("*.py"))
        if p.name != "__init__.py"
    ]


@pytest.mark.parametrize("module", [*_modules("inference/simulation"), "inference.frames"])
def test_the_simulator_imports_no_torch(module):
    assert not any(m.split(".")[0] in ("torch", "onnxruntime") for m in _closure(module)), module


@pytest.mark.parametrize("module", _modules("inference/networks"))
def test_the_networks_are_torch_alone(module):
    """A network module needs torch and numpy, never the simulator, training, onnxruntime or the service."""
    shared = {module, "inference", "inference.networks", "inference.errors", "inference.frames"}
    inner = {m for m in _closure(module) if m.startswith("inference.")} - shared
    assert all(m.startswith("inference.networks") for m in inner), (module, inner)
    assert not any(m.split(".")[0] == "onnxruntime" for m in _closure(module))


def test_each_inference_folder_holds_one_kind():
    assert _modules("inference/simulation") and _modules("inference/networks") and _modules("inference/training")
    assert sorted(p.name for p in (ROOT / "inference/models").glob("*.py")) == ["__init__.py"]  # code lives elsewhere


@pytest.mark.parametrize("module", ["inference.runtime", "inference.frames", "inference.fit", "inference.trust"])
def test_the_runtime_imports_no_torch(module):
    assert not any(m.split(".")[0] == "torch" for m in _closure(module)), module


@pytest.mark.parametrize("package,forbidden", [("planner", ("app", "inference")), ("inference", ("app", "planner"))])
def test_planner_and_inference_never_import_app_or_each_other(package, forbidden):
    bad = [
        (str(p.relative_to(ROOT)), name)
        for p in _package_files(package)
        for name, _ in _imports(p)
        if name.split(".")[0] in forbidden
    ]
    assert not bad, bad


def test_app_imports_no_private_name_of_another_package():
    bad = [
        (str(p.relative_to(ROOT)), module, name)
        for p in _package_files("app")
        for module, names in _imports(p)
        if module.split(".")[0] in ("planner", "inference")
        for name in names
        if name.startswith("_")
    ]
    assert not bad, bad


def test_no_route_module_imports_another():
    routes = ROOT / "app" / "api" / "routes"
    bad = [
        (p.name, module)
        for p in routes.glob("*.py")
        for module, names in _imports(p)
        if module.startswith("app.api.routes") or (module == "app.api" and "routes" in names)
    ]
    assert not bad, bad


def test_no_route_module_holds_sql():
    """Routes read, call a service or crud, and answer: the queries live in app/crud.py."""
    routes = ROOT / "app" / "api" / "routes"
    bad = [
        (p.name, module) for p in routes.glob("*.py") for module, _ in _imports(p) if module.startswith("sqlalchemy")
    ]
    assert not bad, bad


def test_light_entry_points_leave_torch_and_the_simulator_out():
    """`import app.main` and building gsa's parser (what `gsa --help` and `gsa serve` do) import no torch (nor numba), and no
    command module of gsa before its command runs."""
    code = (
        "import json, sys\n"
        "import app.main\n"
        "from app.cli import build_parser\n"
        "build_parser().format_help()\n"
        "heavy = ('torch', 'app.cli.planning', 'app.cli.estimates', 'app.cli.passes', 'app.cli.service', 'inference.simulation.radar', 'inference.simulation.scene', 'inference.simulation.targets', 'inference.simulation.dataset', 'inference.training.train', 'scipy.ndimage', 'numba')\n"
        "print(json.dumps([m for m in heavy if m in sys.modules]))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []


def test_the_planner_surface_names_real_objects_and_costs_nothing_to_import():
    """Every name in ``planner.__all__`` is the object its module defines; ``import planner`` loads none of them."""
    code = (
        "import json, sys\n"
        "import planner\n"
        "before = sorted(m for m in sys.modules if m.startswith('planner.') or m == 'skyfield')\n"
        "import importlib\n"
        "where = vars(planner)['_WHERE']\n"
        "bad = [n for n in planner.__all__ if getattr(planner, n) is not getattr(importlib.import_module('planner.' + where[n]), n)]\n"
        "print(json.dumps([before, bad]))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    before, bad = json.loads(out.stdout.strip().splitlines()[-1])
    assert before == [] and bad == []
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        import planner

        planner.nothing  # noqa: B018

"""The house rules, checked: which folder may import what, and what stays out of the light entry points."""

from __future__ import annotations

import ast
import json
import re
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
            if name.split(".")[0] in ("app", "planner", "inference", "scene"):
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


@pytest.mark.parametrize(
    "package,forbidden",
    [
        ("planner", ("app", "inference", "scene")),
        ("inference", ("app", "planner", "scene")),
        ("scene", ("app", "fastapi", "starlette", "pydantic", "sqlalchemy", "alembic")),
    ],
)
def test_the_halves_meet_only_in_the_scene_and_the_app(package, forbidden):
    """planner and inference never import each other, the scene or the app; the scene (which joins them) imports
    no app and no web or database library."""
    bad = [
        (str(p.relative_to(ROOT)), name)
        for p in _package_files(package)
        for name, _ in _imports(p)
        if name.split(".")[0] in forbidden
    ]
    assert not bad, bad


@pytest.mark.parametrize("folder", ["app/cli", "bench"])
def test_the_command_line_and_the_benchmarks_reach_the_numerics_through_the_scene(folder):
    """The pass and estimate geometry, simulation and fusion are the scene's: the CLI and bench never take them
    from the web layer's services (the CLI's client commands may still call the service functions it shares)."""
    numerics = ("app.services.passes", "app.services.estimation")
    allowed = {("app.services.passes", "pass_record"), ("app.services.estimation", "prepare_frames")}
    bad = [
        (str(p.relative_to(ROOT)), module, name)
        for p in sorted((ROOT / folder).glob("*.py"))
        for module, names in _imports(p)
        if module in numerics
        for name in names
        if (module, name) not in allowed
    ]
    assert not bad, bad


def test_the_pass_benchmark_needs_no_app():
    """bench/passes.py benchmarks numerical methods: the scene, the planner and inference, never the web layer."""
    assert not [m for m, _ in _imports(ROOT / "bench" / "passes.py") if m.split(".")[0] == "app"]


def _route_functions(method: str) -> list[tuple[str, ast.AsyncFunctionDef | ast.FunctionDef]]:
    """Every route handler for ``method`` (decorated ``@router.<method>(...)``), with its file's name."""
    out = []
    for p in sorted((ROOT / "app" / "api" / "routes").glob("*.py")):
        for node in ast.parse(p.read_text()).body:
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                for d in node.decorator_list:
                    f = d.func if isinstance(d, ast.Call) else d
                    if isinstance(f, ast.Attribute) and f.attr == method:
                        out.append((p.name, node))
    return out


def test_no_route_writes_the_database_itself():
    """Routes validate, call a service and answer: no ``session.add``, ``add_all``, ``commit`` in a route module."""
    bad = []
    for p in sorted((ROOT / "app" / "api" / "routes").glob("*.py")):
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.Attribute) and node.attr in ("add", "add_all", "commit", "flush", "delete"):
                if isinstance(node.value, ast.Name) and node.value.id == "session":
                    bad.append((p.name, node.lineno, node.attr))
    assert not bad, bad


def _service_names(path: Path) -> tuple[set[str], set[str]]:
    """The names a route module binds to ``app.services`` and ``app.crud``: modules (``svc``, ``crud``), functions."""
    services = {m.rsplit(".", 1)[-1] for m in _modules("app/services")}
    modules, functions = set(), set()
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.ImportFrom) and node.module:
            for a in node.names:
                bound = a.asname or a.name
                if node.module in ("app", "app.services") and a.name in ("crud", *services):
                    modules.add(bound)
                elif node.module.startswith("app.services.") or node.module == "app.crud":
                    functions.add(bound)
    return modules, functions


def test_every_post_route_calls_one_service():
    """A POST handler hands its work to one function of ``app.services`` or ``app.crud``, named once; one that may
    also answer 202 (``Prefer: respond-async``) hands it there to one ``submit_*``, which queues it as a job."""
    handlers = _route_functions("post")
    assert len(handlers) >= 6  # plans, access, estimates (one and a batch), passes, stations
    for name, fn in handlers:
        modules, functions = _service_names(ROOT / "app" / "api" / "routes" / name)
        refs = [
            ast.unparse(n)
            for stmt in fn.body
            for n in ast.walk(stmt)
            if (isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name) and n.value.id in modules)
            or (isinstance(n, ast.Name) and n.id in functions)
        ]
        queued = [r for r in refs if r.rpartition(".")[2].startswith("submit_")]
        assert len(refs) == 1 or (len(refs) == 2 and len(queued) == 1), (name, fn.name, refs)


def test_app_imports_no_private_name_of_another_package():
    bad = [
        (str(p.relative_to(ROOT)), module, name)
        for p in _package_files("app")
        for module, names in _imports(p)
        if module.split(".")[0] in ("planner", "inference", "scene")
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


def test_the_image_copies_every_package_the_project_installs():
    """The Dockerfile copies each package `pip install -e .` finds (pyproject's packages.find), so the image imports
    what the code imports (scene/ was missing from it)."""
    import tomllib

    include = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]["include"]
    copied = set(re.findall(r"^COPY (\w+) \./\1$", (ROOT / "Dockerfile").read_text(), re.M))
    assert {name.rstrip("*") for name in include} <= copied, copied

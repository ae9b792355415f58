import subprocess
import sys


def test_planner_imports_no_web_or_database_code():
    code = (
        "import sys, planner.plan, planner.access, planner.lambert; "
        "bad = [m for m in ('fastapi', 'pydantic', 'sqlalchemy', 'app', 'inference') if m in sys.modules]; "
        "print(','.join(bad))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


def test_simulator_needs_only_numpy_and_scipy():
    code = (
        "import sys, inference.dataset, inference.isar, inference.targets; "
        "bad = [m for m in ('fastapi', 'pydantic', 'sqlalchemy', 'app', 'planner', 'skyfield', 'torch') "
        "if m in sys.modules]; print(','.join(bad))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""

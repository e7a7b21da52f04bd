"""The import rules of docs/architecture.md hold: layers import only downwards, no cycles.

scripts/import_graph.py reads every import of backend/ and worker/ (also those inside
functions), maps each module to its layer and checks the rules; it is the same command
anyone can run to see the graph.
"""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "import_graph.py"


def run_graph(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(SCRIPT), *args], capture_output=True, text=True, check=False
    )


def test_layers_import_only_downwards_without_cycles() -> None:
    result = run_graph("--layers")
    assert "cycles: 0" in result.stdout, result.stdout
    assert "imports that break a rule: 0" in result.stdout, result.stdout
    assert result.returncode == 0


def test_the_library_imports_no_platform_layer() -> None:
    graph = dict(
        line.split(" -> ") for line in run_graph("--layers").stdout.splitlines() if " -> " in line
    )
    assert set(graph.get("library", "").split(", ")) <= {""}, graph


def test_no_cycles_between_top_level_packages() -> None:
    """Packages inside one layer may lean on each other (the library's subpackages share
    its error types); across layers the package graph has no cycle."""
    result = run_graph()
    cycles = result.stdout.split("cycles:")[1].splitlines()[1:]
    layered = [c for c in cycles if "backend" in c or "worker.jobs" in c or "simulator" in c]
    assert layered == [], result.stdout


def test_no_module_imports_itself_back_through_others() -> None:
    """Not even inside one package, nor through a function-local or type-only import."""
    result = run_graph("--modules")
    assert result.stdout.startswith("module cycles: 0"), result.stdout
    assert result.returncode == 0


def test_the_rules_catch_an_import_against_them(tmp_path: Path) -> None:
    """The checker itself: a library module that imports the job layer is reported."""
    for package in ("backend", "worker", "worker/pipeline", "worker/jobs"):
        (tmp_path / package).mkdir(parents=True, exist_ok=True)
        (tmp_path / package / "__init__.py").write_text("")
    (tmp_path / "worker/jobs/runner.py").write_text("")
    (tmp_path / "worker/pipeline/bad.py").write_text("from worker.jobs import runner\n")
    result = run_graph("--layers", "--root", str(tmp_path))
    assert result.returncode == 1
    assert "worker/pipeline/bad.py:1: library imports jobs" in result.stdout

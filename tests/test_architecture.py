"""The package's guards: the import contract of pyproject.toml (layers that point one way, features
below the estimators, no import cycle, function-level imports counted: import-linter reads every import statement),
ruff's checks and limits, and the modules' sizes. Each guard is shown to fail on a tree that breaks it."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 500
# modules past MAX_LINES today, each to be split along its concerns; a module here may shrink, never grow
OVERSIZED = {
    "fviz/record/layout.py": 550,
}


def _lint_imports(tree: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    return subprocess.run([sys.executable, "-c", "from importlinter.cli import lint_imports_command as c; c()",
                           "--no-cache", str(tree / "pyproject.toml")], cwd=tree, env=env, capture_output=True,
                          text=True, timeout=300)


def test_the_import_contract_holds():
    r = _lint_imports(ROOT)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert "3 kept, 0 broken" in r.stdout


@pytest.mark.parametrize("module, line, contract", [
    ("fviz/geometry/residuals.py", "    from fviz.record import layout  # noqa: F401", "layers: each imports only those below it BROKEN"),
    ("fviz/data/pair.py", "    from fviz.data.kitti import open_dataset  # noqa: F401", "no import cycle BROKEN"),
])
def test_the_import_contract_catches_an_upward_import_or_a_cycle_inside_a_function(tmp_path, module, line, contract):
    """A copy of the tree with one function-level import added: geometry importing the recording layer (upward);
    the Pair type importing the KITTI source, which imports it (a cycle)."""
    shutil.copytree(ROOT / "fviz", tmp_path / "fviz", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    path = tmp_path / module
    path.write_text(path.read_text() + f"\n\ndef _added():\n{line}\n")
    r = _lint_imports(tmp_path)
    assert r.returncode != 0 and contract in r.stdout, r.stdout[-3000:]


# The command line is a client of fviz.api: each command parses its flags and calls the API. What a cli module may
# import besides fviz.api, fviz.errors and fviz.cli, each with its reason (to move behind fviz.api next; fewer is better).
CLI_OWN = ("fviz.api", "fviz.errors", "fviz.cli")
CLI_EXCEPTIONS: dict[str, dict[str, str]] = {}


def _cli_imports(tree: Path) -> dict[str, list[str]]:
    """{cli module: the fviz modules it imports (at any level) that are not fviz.api*, fviz.errors or fviz.cli*}."""
    code = ("import grimp, json\ng = grimp.build_graph('fviz')\n"
            "own = lambda m: any(m == p or m.startswith(p + '.') for p in %r)\n"
            "print(json.dumps({m: sorted(i for i in g.find_modules_directly_imported_by(m) if not own(i))\n"
            "                  for m in sorted(g.modules) if m == 'fviz.cli' or m.startswith('fviz.cli.')}))" % (CLI_OWN,))
    import json

    r = subprocess.run([sys.executable, "-c", code], cwd=tree, env={**os.environ, "PYTHONPATH": str(tree)},
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    return {m: imported for m, imported in json.loads(r.stdout).items() if imported}


def _beyond_exceptions(imports: dict[str, list[str]]) -> dict[str, list[str]]:
    out = {m: [i for i in imported if i not in CLI_EXCEPTIONS.get(m, {})] for m, imported in imports.items()}
    return {m: imported for m, imported in out.items() if imported}


def test_the_command_line_imports_only_fviz_api():
    imports = _cli_imports(ROOT)
    assert not _beyond_exceptions(imports), f"cli modules import past fviz.api: {_beyond_exceptions(imports)}"
    stale = {m: sorted(set(e) - set(imports.get(m, ()))) for m, e in CLI_EXCEPTIONS.items()}
    assert not any(stale.values()), f"exceptions no longer needed (remove them): {stale}"


@pytest.mark.parametrize("module, line", [
    ("fviz/cli/eval.py", "    from fviz.run import run_eval  # noqa: F401"),
    ("fviz/cli/table.py", "    import fviz.table  # noqa: F401"),
])
def test_the_cli_contract_catches_an_import_past_fviz_api(tmp_path, module, line):
    """A copy of the tree where a command imports the run (or the table) itself instead of calling fviz.api."""
    shutil.copytree(ROOT / "fviz", tmp_path / "fviz", ignore=shutil.ignore_patterns("__pycache__"))
    path = tmp_path / module
    path.write_text(path.read_text() + f"\n\ndef _added():\n{line}\n")
    beyond = _beyond_exceptions(_cli_imports(tmp_path))
    name = module[:-3].replace("/", ".")
    assert name in beyond and beyond[name][0] in ("fviz.run", "fviz.table"), beyond


def test_ruff_passes():
    r = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "fviz", "tests", "benchmarks", "examples"],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-2000:]


def test_ruff_catches_a_function_past_its_limits(tmp_path):
    """The limits are set (complexity 20, 80 statements): a function of 21 branches is refused."""
    body = "".join(f"    if x == {i}:\n        return {i}\n" for i in range(21))
    (tmp_path / "m.py").write_text(f"def f(x):\n{body}    return -1\n")
    r = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "--config", str(ROOT / "pyproject.toml"),
                        str(tmp_path / "m.py")], capture_output=True, text=True, timeout=300)
    assert r.returncode != 0 and "C901" in r.stdout, r.stdout


def test_no_module_grows_past_its_size():
    sizes = {str(p.relative_to(ROOT)): len(p.read_text().splitlines()) for p in (ROOT / "fviz").rglob("*.py")}
    over = {m: n for m, n in sizes.items() if n > OVERSIZED.get(m, MAX_LINES)}
    assert not over, f"past {MAX_LINES} lines (or past their size today, OVERSIZED): {over}; split them along their concerns"
    assert all(m in sizes for m in OVERSIZED)

"""The house keeps its shape (SPEC §1, the design card): three import packages, `mesh` <- `tdgen` <-
`devices`, imports only going down, inside each package too, no file-level cycle; click only in CLI
modules (all of it said as configuration: pyproject's [tool.importlinter]); no module named by a string
(a typo must fail at import, not after a spawn)."""
from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ["mesh", "tdgen", "devices"]  # lower to higher
# a dotted name of ours, optionally with `:function` (how processes used to be wired)
OUR_MODULE_STRING = re.compile(r"^(mesh|tdgen|devices)(\.[a-z_]\w*)+(:\w+)?$")


def _code_files() -> list[Path]:
    tracked = subprocess.run(["git", "ls-files", "*.py"], cwd=REPO, capture_output=True, text=True, check=True)
    return [REPO / f for f in tracked.stdout.split() if (REPO / f).exists()]


def _our_modules(path: Path) -> list[Path]:
    return [p for p in sorted((REPO / path).rglob("*.py")) if "__pycache__" not in p.parts]


def test_all_code_lives_in_the_three_packages():
    """Every tracked .py outside tests/, docs/ and examples/ is under mesh/, tdgen/ or devices/, each a package."""
    strays = [str(p.relative_to(REPO)) for p in _code_files()
              if p.relative_to(REPO).parts[0] not in (*PACKAGES, "tests", "docs", "examples")]
    assert strays == [], f"code outside mesh/, tdgen/, devices/: {strays}"
    for package in PACKAGES:
        assert (REPO / package / "__init__.py").is_file(), f"{package}/ is not an import package"


def test_the_import_contracts_hold():
    """The layers (mesh <- tdgen <- devices, and the rooms inside each), no cycle among a room's modules,
    click only in CLI rooms, only the gateway touching Zenoh inside http/: pyproject's [tool.importlinter]."""
    run = subprocess.run([str(Path(sys.executable).parent / "lint-imports"), "--no-cache"], cwd=REPO,
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]


def test_no_module_is_named_by_a_string():
    """Processes and lazy commands hold functions, not `module:function` strings; nothing imports by name."""
    found = []
    for pkg in PACKAGES:
        for path in _our_modules(Path(pkg)):
            tree = ast.parse(path.read_text())
            for node in ast.walk(tree):
                if isinstance(node, ast.Constant) and isinstance(node.value, str) and OUR_MODULE_STRING.match(node.value):
                    found.append(f"{path.relative_to(REPO)}:{node.lineno}: {node.value!r}")
                if isinstance(node, ast.Call):
                    f = node.func
                    name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
                    if name in ("import_module", "__import__"):
                        found.append(f"{path.relative_to(REPO)}:{node.lineno}: {name}()")
    assert found == [], "modules named by strings:\n" + "\n".join(found)


def test_the_public_surface_of_mesh():
    import mesh

    assert callable(mesh.consume) and callable(mesh.consumer)
    assert {"Problem", "MeshSettings", "consume"} <= set(mesh.__all__)

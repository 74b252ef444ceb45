"""The house keeps its shape (SPEC §1, the design card): three import packages, `mesh` <- `tdgen` <-
`devices`, imports only going down, inside each package too; click only in CLI modules; no module
named by a string (a typo must fail at import, not after a spawn)."""
from __future__ import annotations

import ast
import re
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ["mesh", "tdgen", "devices"]  # lower to higher
# each package's parts, lower to higher: a part imports only parts before it (and itself)
PARTS = {
    "mesh": ["wot", "messages", "urdf_resources", "process", "fabric", "http", "bridge", "recorder", "__init__", "cli"],
    "tdgen": ["robot", "cache", "sampling", "points_csv", "robot_td", "generate", "live", "service", "__init__", "cli"],
    "devices": ["planning", "sim", "things", "apps", "lab", "cli", "__main__", "__init__"],
}
# a dotted name of ours, optionally with `:function` (how processes used to be wired)
OUR_MODULE_STRING = re.compile(r"^(mesh|tdgen|devices)(\.[a-z_]\w*)+(:\w+)?$")


def _code_files() -> list[Path]:
    tracked = subprocess.run(["git", "ls-files", "*.py"], cwd=REPO, capture_output=True, text=True, check=True)
    return [REPO / f for f in tracked.stdout.split() if (REPO / f).exists()]


def _our_modules(path: Path) -> list[Path]:
    return [p for p in sorted((REPO / path).rglob("*.py")) if "__pycache__" not in p.parts]


def _imported(path: Path) -> set[str]:
    """Every module a file imports, at top level or inside functions (relative imports resolved)."""
    rel = path.relative_to(REPO).with_suffix("")
    package = list(rel.parts[:-1])
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            names.add(module)
            names.update(f"{module}.{a.name}" for a in node.names)  # `from mesh import cli` imports mesh.cli
    return names


def _part(dotted: str) -> tuple[str, str] | None:
    bits = dotted.split(".")
    if bits[0] not in PACKAGES:
        return None
    part = bits[1] if len(bits) > 1 and bits[1] in PARTS[bits[0]] else "__init__"
    return bits[0], part


def _where(path: Path) -> tuple[str, str]:
    rel = path.relative_to(REPO).with_suffix("")
    part = rel.parts[1] if len(rel.parts) > 1 else "__init__"
    return rel.parts[0], part


def test_all_code_lives_in_the_three_packages():
    """Every tracked .py outside tests/ and docs/ is under mesh/, tdgen/ or devices/, each a package."""
    strays = [str(p.relative_to(REPO)) for p in _code_files()
              if p.relative_to(REPO).parts[0] not in (*PACKAGES, "tests", "docs")]
    assert strays == [], f"code outside mesh/, tdgen/, devices/: {strays}"
    for package in PACKAGES:
        assert (REPO / package / "__init__.py").is_file(), f"{package}/ is not an import package"
        unknown = {_where(p)[1] for p in _our_modules(Path(package))} - set(PARTS[package])
        assert not unknown, f"{package}/ has parts this test does not place: {sorted(unknown)}"


def test_imports_only_go_down():
    """mesh imports neither tdgen nor devices; tdgen does not import devices; inside a package, a part
    imports only the parts listed before it (functions' own imports included)."""
    broken = []
    for package in PACKAGES:
        for path in _our_modules(Path(package)):
            me_pkg, me_part = _where(path)
            for name in _imported(path):
                other = _part(name)
                if other is None:
                    continue
                pkg, part = other
                rel = path.relative_to(REPO)
                if PACKAGES.index(pkg) > PACKAGES.index(me_pkg):
                    broken.append(f"{rel} imports {name} (a higher package)")
                elif pkg == me_pkg and part != me_part and PARTS[pkg].index(part) > PARTS[pkg].index(me_part):
                    broken.append(f"{rel} imports {name} ({pkg}.{part} stands above {pkg}.{me_part})")
    assert not broken, "\n".join(broken)


def test_click_only_in_command_line_modules():
    users = [str(p.relative_to(REPO)) for pkg in PACKAGES for p in _our_modules(Path(pkg))
             if any(n == "click" or n.startswith("click.") for n in _imported(p)) and "cli" not in p.parts]
    assert users == [], f"click outside the cli packages: {users}"


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


def test_inside_http_only_the_gateway_touches_the_zenoh_binding():
    """The HTTP binding knows the mesh through its gateway (the registry, which also opens its sessions)."""
    allowed = {"gateway.py"}
    touching = sorted(p.name for p in (REPO / "mesh" / "http").glob("*.py")
                      if any(n.startswith("mesh.fabric") for n in _imported(p)) and p.name not in allowed)
    assert touching == [], f"http modules importing mesh.fabric besides the gateway: {touching}"


def test_the_public_surface_of_mesh():
    import mesh

    assert callable(mesh.consume) and callable(mesh.consumer)
    assert {"Problem", "MeshSettings", "consume"} <= set(mesh.__all__)

"""The package keeps its house: each part of `twinmesh` imports only the parts listed before it."""
from __future__ import annotations

import ast
from pathlib import Path

import twinmesh

ORDER = ["wot", "messages", "fabric", "http", "robot", "tdgen", "sim", "things", "recorder", "apps", "lab", "cli"]
ROOT = Path(twinmesh.__file__).parent


def _imports(path: Path) -> set[str]:
    """The `twinmesh` parts a module imports, at top level or inside functions."""
    parts = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        for name in names:
            bits = name.split(".")
            if bits[0] == "twinmesh" and len(bits) > 1:
                parts.add(bits[1])
    return parts


def test_every_module_sits_in_a_known_part():
    strays = [p.relative_to(ROOT).parts[0] for p in ROOT.rglob("*.py")
              if len(p.relative_to(ROOT).parts) > 1 and p.relative_to(ROOT).parts[0] not in ORDER]
    assert not strays, f"modules outside the house's parts: {sorted(set(strays))}"


def test_parts_import_only_parts_before_them():
    broken = []
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT)
        if len(rel.parts) == 1:
            continue  # twinmesh/__init__.py, __main__.py: the face of the package
        me = rel.parts[0]
        for other in _imports(path) - {me}:
            if ORDER.index(other) > ORDER.index(me):
                broken.append(f"{rel} imports twinmesh.{other}")
            elif other == "lab" and me != "cli":
                broken.append(f"{rel} imports twinmesh.lab (only the CLI may)")
    assert not broken, "\n".join(broken)


def test_inside_http_only_the_gateway_touches_the_zenoh_binding():
    """The HTTP binding knows the mesh through its gateway (the registry); `server.py`, the adapter
    process's entry point, opens the session it hands to the gateway."""
    allowed = {"gateway.py", "server.py"}
    touching = sorted(p.name for p in (ROOT / "http").glob("*.py") if "fabric" in _imports(p) and p.name not in allowed)
    assert touching == [], f"http modules importing twinmesh.fabric besides the gateway: {touching}"

"""The iot-platform devices' TDs, as served on Zenoh and through the HTTP adapter, against the real lab's.

Each device TD must carry the affordances of its real-lab TD (tests/data/reference-tds/real-lab/)
with the same schemas (type, minimum/maximum, required, readOnly, observable, const, items...),
compared by name, except the deviations listed in ALLOWED below, each with its reason. `type`
may be added where the real TD has none (SPEC §5: `type` on every data schema). Every TD is valid
against the official TD 1.1 schema.
"""
from __future__ import annotations

import fnmatch
import json
from typing import Any

import httpx
import numpy as np
import pytest
from labs import PLATFORM_THINGS, mesh_client
from tdschema import REFERENCE_TDS, assert_valid_td

from mesh.messages.relations import MODEL, SCENE

REAL = {
    "dobot": "WarehouseDobot.json",
    "conveyor-belt-1": "ConveyorBelt1.json",
    "conveyor-belt-2": "ConveyorBelt2.json",
    "infrared-sensor-1": "InfraredSensor1.json",
    "infrared-sensor-2": "InfraredSensor2.json",
    "color-sensor": "ColorSensor.json",
    "uarm": "Uarm.json",
}
THINGS = set(PLATFORM_THINGS)
assert THINGS == set(REAL) | {"world"}

# The documented deviations from the real TDs: path pattern (fnmatch) -> why. A difference must
# match one of them, and each of them must still be needed (no stale entries).
ALLOWED = {
    # SPEC §5 / the issue: every twin action answers when it is over, so every action says
    # `synchronous: true`; the real Dobot actions and stopBelt say false, the uArm's say nothing
    "*/actions/*/synchronous": "synchronous: true everywhere",
    # SPEC §3: an affordance that makes no sense in simulation may be left out (sound)
    "uarm/actions/beep": "no sound in simulation",
    "uarm/actions/beepWithTime": "no sound in simulation",
    # the real `location` declares the goTo box, but the arm stands at homeLoc points outside it
    # (x 50..250, y -330..330) and passes outside it between two points; node-wot validates what
    # it reads, so the twin declares the arm's whole reach (devices.things.platform_things.LOCATION_RANGE)
    "uarm/properties/location/properties/[xyz]/minimum": "location: the arm's whole reach",
    "uarm/properties/location/properties/[xyz]/maximum": "location: the arm's whole reach",
    # a TD offers only what a handler serves (mesh.fabric.server.ExposedThing._truthful): the twin's location is
    # where its joints put it, so it is read-only (the real TD says writable, yet no write could move it)
    "uarm/properties/location/readOnly": "location: read-only, as the twin serves it",
    # the same rule: a beam reading cannot be set, so the twin registers no write for it
    "infrared-sensor-*/properties/objectPresence/readOnly": "objectPresence: a reading, read-only",
}
# TD 1.1 §5.3.2 / the issue: units from one vocabulary (QUDT, `qudt:` declared in @context); the real
# belts' `%` is qudt:PERCENT, and the real TDs' unit-less numbers (mm, deg, lux, K...) get theirs
ALLOWED["*/unit"] = "units from the QUDT vocabulary"
IGNORED = {"forms", "description", "title"}  # titles are the real ones; descriptions carry twin notes


def differences(real: Any, twin: Any, path: str) -> list[str]:
    """Paths where `twin` differs from `real` (a missing or extra `type` on the twin's side is fine)."""
    if isinstance(real, dict) and isinstance(twin, dict):
        out = []
        for key in sorted(set(real) | set(twin)):
            if key in IGNORED:
                continue
            if key not in twin:
                out.append(f"{path}/{key}")
            elif key not in real:
                if key != "type":
                    out.append(f"{path}/{key}")
            else:
                out += differences(real[key], twin[key], f"{path}/{key}")
        return out
    return [] if real == twin else [path]


def td_differences(slug: str, twin: dict) -> list[str]:
    real = json.loads((REFERENCE_TDS / "real-lab" / REAL[slug]).read_text())
    out = []
    for kind in ("properties", "actions", "events"):
        r, t = real.get(kind, {}), twin.get(kind, {})
        for name in sorted(set(r) | set(t)):
            where = f"{slug}/{kind}/{name}"
            if name not in t or name not in r:
                out.append(where)
            else:
                out += differences(r[name], t[name], where)
    return out


# What a served TD adds to the twin's own (forms are compared by nobody): every action can also be
# invoked asynchronously, and its queryaction/cancelaction forms name the invocation by an `id` variable
SERVED = {"*/actions/*/uriVariables": "uriVariables: the id of an asynchronous invocation"}


def assert_like_the_real_td(slug: str, twin: dict, served: bool = True) -> set[str]:
    """Every difference is allowed; returns the allow-list patterns that were used."""
    diffs = td_differences(slug, twin)
    allowed = {**ALLOWED, **SERVED} if served else ALLOWED
    unexplained = [d for d in diffs if not any(fnmatch.fnmatchcase(d, p) for p in allowed)]
    assert not unexplained, f"{slug} differs from its real TD at: {unexplained}"
    assert all(a.get("synchronous") is True for a in twin.get("actions", {}).values())
    return {p for p in ALLOWED if any(fnmatch.fnmatchcase(d, p) for d in diffs)}


# --- without a lab: the TDs the devices are built with --------------------------------------------
def test_twin_tds_have_the_real_affordances_and_schemas_with_only_the_documented_deviations():
    from devices.things.platform_things import PLATFORM_DEVICES, twin_td

    assert set(PLATFORM_DEVICES) == set(REAL)
    used: set[str] = set()
    for slug in PLATFORM_DEVICES:
        used |= assert_like_the_real_td(slug, twin_td(slug).to_dict(), served=False)
    assert used == set(ALLOWED), f"stale allow-list entries: {set(ALLOWED) - used}"


def test_twin_tds_say_their_deviations_in_their_descriptions():
    from devices.things.platform_things import twin_td

    assert "objectPresence is a beam reading, read-only" in twin_td("infrared-sensor-1").description
    assert "every change" in twin_td("infrared-sensor-2").description
    uarm = twin_td("uarm").description
    assert "beep" in uarm and "whole reach" in uarm and "turnRight" in uarm and "reset moves nothing" in uarm
    assert "synchronous" in twin_td("dobot").description and "synchronous" in twin_td("conveyor-belt-1").description


def test_the_declared_location_range_holds_every_position_the_uarm_can_take():
    """node-wot validates read values: `location` must never leave its declared ranges (all motor angles)."""
    from devices.sim.uarm import BETWEEN_ARMS_DEG, LIMITS_DEG, real_fk
    from devices.things.platform_things import LOCATION_RANGE

    grids = [np.radians(np.linspace(*LIMITS_DEG[j], n)) for j, n in
             (("base", 61), ("lower_arm", 160), ("upper_arm", 160))]
    c, a, b = (g.ravel() for g in np.meshgrid(*grids, indexing="ij"))
    between = 180.0 - np.degrees(a) - np.degrees(b)
    ok = (between >= BETWEEN_ARMS_DEG[0]) & (between <= BETWEEN_ARMS_DEG[1])
    points = np.round(real_fk(np.stack([c[ok], a[ok], b[ok]], axis=1)))
    for i, axis in enumerate("xyz"):
        lo, hi = LOCATION_RANGE[axis]
        assert lo <= points[:, i].min() and points[:, i].max() <= hi, axis
        assert points[:, i].max() > hi - 15 and points[:, i].min() < lo + 15, f"{axis}: range not tight"


# --- served by a running lab ----------------------------------------------------------------------
@pytest.fixture(scope="module")
def lab(platform):
    return platform  # the session's iot-platform lab, lent to this module (conftest.py)


@pytest.mark.lab
def test_tds_on_zenoh_match_the_real_ones_and_are_valid(lab):
    with mesh_client(lab.endpoint) as client:
        tds = {slug: json.loads(client.td_bytes(slug)) for slug in THINGS}
    for slug in REAL:
        assert_like_the_real_td(slug, tds[slug])
    for slug, td in tds.items():
        assert td["id"] == f"urn:twinmesh:thing:{slug}"
        assert_valid_td(td)


@pytest.mark.lab
def test_tds_through_the_adapter_match_the_real_ones_and_are_valid(lab):
    for slug in sorted(THINGS):
        r = httpx.get(f"{lab.http}/{slug}")
        assert r.status_code == 200 and r.headers["content-type"].startswith("application/td+json")
        td = r.json()
        assert_valid_td(td)
        if slug in REAL:
            assert_like_the_real_td(slug, td)
            real = json.loads((REFERENCE_TDS / "real-lab" / REAL[slug]).read_text())
            observable = {n for n, p in real.get("properties", {}).items() if p.get("observable")}
            for name in observable:  # what the real TD marks observable can be observed here too
                ops = {op for f in td["properties"][name]["forms"] for op in f["op"]}
                assert "observeproperty" in ops, (slug, name)


@pytest.mark.lab
def test_the_world_td_links_the_scene_and_each_robots_urdf(lab):
    td = httpx.get(f"{lab.http}/world").json()
    links = td["links"]
    scene = [link for link in links if link["rel"] == SCENE]
    models = {link["anchor"]: link for link in links if link["rel"] == MODEL}
    assert scene and scene[0]["href"] == f"{lab.http}/world/files/scene.json"
    assert set(models) == {"urn:twinmesh:thing:uarm", "urn:twinmesh:thing:dobot"}
    assert models["urn:twinmesh:thing:uarm"]["href"] == f"{lab.http}/world/files/uarm.urdf"
    poses = td["properties"]["poses"]
    assert poses["observable"] is True and poses["readOnly"] is True
    assert td["properties"]["speed"].get("readOnly") is not True
    assert {"reset", "resetWarehouse"} <= set(td["actions"])


def test_the_comparison_sees_a_changed_bound_a_lost_flag_and_a_missing_affordance():
    from devices.things.platform_things import twin_td

    td = twin_td("conveyor-belt-1").to_dict()
    td["properties"]["speed"]["maximum"] = 200
    del td["properties"]["speed"]["readOnly"]
    del td["actions"]["stopBelt"]
    assert td_differences("conveyor-belt-1", td) == [
        "conveyor-belt-1/properties/speed/maximum", "conveyor-belt-1/properties/speed/readOnly",
        "conveyor-belt-1/properties/speed/unit",  # allowed: qudt:PERCENT for the real TD's "%"
        "conveyor-belt-1/actions/stopBelt"]

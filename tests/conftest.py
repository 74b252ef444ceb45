"""Shared fixtures: one lab per scene per test session, lent to each module that needs it.

Starting a lab is most of a lab test's time, so the modules that used to start the same `lights` lab
(or `iot-platform --speed max`) borrow one started once here. A module gets it as the scene starts:
the lights off and white, the platform's world reset; what the module started on the lab's mesh
(robots, devices, recorders: `lab.spawn`) is stopped when the module ends, and the lab's own Things
must be listed alone again before the next module borrows it. The lab stops with the session, and
must stop cleanly.

The `iot-lab` and the `iot-platform` lab are shared the same way by the modules that borrow them
(`iot_lab`, `platform`); a session fixture lives once per xdist worker, so those modules are one unit of
work each (`SHARED_LAB`), run by one worker, and the lab stops when the unit's last module is done (an
idle lab steps its physics world in real time); every other module is a unit of its own, as under
`--dist loadfile`. (xdist's own `xdist_group`
marks do nothing with pytest 9: `--dist loadgroup` then hands out every test alone.)

Test helpers (`labs`, `waiting`, `probe`, `recordings`, `arms`, `zoo`, `tdschema`, `interop`) are
modules of this folder: test modules import from them, never from each other.
"""
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from labs import PLATFORM_THINGS, Lab, SharedLab, start_lab, start_robot_lab  # noqa: E402
from waiting import eventually  # noqa: E402

# modules that borrow one session lab, by the xdist unit of work that keeps them on one worker: the lab
# stops when the unit's last module is done (`_last_of_unit`), not idle until the session ends
SHARED_LAB = {"tests/test_fuzz_affordances.py": "iot-lab", "tests/test_iot_lab.py": "iot-lab",
              "tests/test_td_conformance.py": "iot-lab",
              "tests/test_examples.py": "iot-platform", "tests/test_platform_tds.py": "iot-platform",
              "tests/test_platform_mesh.py": "iot-platform", "tests/test_workflow.py": "iot-platform"}
IOT_LAB_THINGS = PLATFORM_THINGS | {"ur10", "light-left", "light-right", "pan-tilt-1", "pan-tilt-2", "tdgen"}
LIGHTS_THINGS = frozenset({"light-left", "light-right", "tdgen"})  # `up` always starts the TD generator
PLATFORM_LISTED = PLATFORM_THINGS | {"tdgen"}


@pytest.fixture(scope="session")
def ur10():
    """The UR10 written from its DH parameters (tdgen/robot/models/ur10.urdf)."""
    from tdgen.robot.model import Robot

    return Robot.load("ur10.urdf")


@pytest.fixture(scope="session")
def scene():
    """The shipped `table-and-wall` scene: a table, a wall beside it, the robot on the table."""
    from tdgen.robot.surroundings import load_scene

    return load_scene("table-and-wall")


def _listed(lab: Lab) -> set[str]:
    return {td["title"] for td in httpx.get(f"{lab.http}/things", timeout=30).json()}


@contextmanager
def lend(lab: Lab, things: frozenset[str], reset) -> Iterator[Lab]:
    """`lab` for one module: reset first; afterwards what the module spawned is stopped and only the
    lab's own `things` are listed (a Thing that leaves is gone from the listing once its token is)."""
    eventually(lambda: _listed(lab) == things, timeout=120, what=f"only {sorted(things)} listed")
    reset(lab)
    try:
        yield lab
    finally:
        clean = lab.stop_extra()
        assert lab.proc.poll() is None, f"the shared lab exited\n{lab.log.read_text()[-4000:]}"
        assert clean, "a process the module started on the shared lab did not stop on Ctrl-C"


def _lights_off(lab: Lab) -> None:
    for light in ("light-left", "light-right"):
        r = httpx.put(f"{lab.http}/{light}/properties", json={"lightState": False, "lightColor": [1.0, 1.0, 1.0]},
                      timeout=30)
        assert r.status_code == 204, r.text


def _world_reset(lab: Lab) -> None:
    r = httpx.post(f"{lab.http}/world/actions/reset", timeout=120)
    assert r.status_code in (200, 204), r.text


@pytest.fixture(scope="session")
def tdgen_cache(tmp_path_factory) -> Path:
    """One TD generator cache for the session's iot-labs: the UR10 with the same samples is generated once
    (the cache key covers every input, so a lab that differs in any of them generates its own)."""
    return tmp_path_factory.mktemp("tdgen-cache")


@pytest.fixture(scope="session")
def lights_lab(tmp_path_factory) -> Iterator[Lab]:
    """`twinmesh up lights` with the adapter and a tdgen cache (`start_robot_lab`): robots may join it."""
    lab = start_robot_lab(tmp_path_factory.mktemp("shared-lights"))
    yield lab
    assert lab.stop(), "the shared lights lab did not stop cleanly on Ctrl-C"


@pytest.fixture(scope="module")
def lights(lights_lab) -> Iterator[Lab]:
    """The shared lights lab, lights off and white, for this module."""
    with lend(lights_lab, LIGHTS_THINGS, _lights_off) as lab:
        yield lab


def _last_of_unit(request: pytest.FixtureRequest) -> bool:
    """Whether the requesting module is the last of its `SHARED_LAB` unit this session runs: after it, no
    module borrows that unit's lab again (the unit runs whole on one worker, in the session's order)."""
    module = request.node.nodeid.split("::", 1)[0]
    unit = SHARED_LAB.get(module)
    modules = [m for m in (item.nodeid.split("::", 1)[0] for item in request.session.items) if SHARED_LAB.get(m) == unit]
    return unit is not None and modules[-1:] == [module]


@pytest.fixture(scope="session")
def platform_lab(tmp_path_factory) -> Iterator[SharedLab]:
    """`twinmesh up iot-platform --speed max` with the adapter, started when a module first borrows it."""
    shared = SharedLab(lambda: start_lab(tmp_path_factory.mktemp("shared-platform"), "iot-platform", http=True,
                                         things=set(PLATFORM_LISTED), extra_args=("--speed", "max")),
                       "the shared iot-platform lab")
    yield shared
    shared.close()


@pytest.fixture(scope="module")
def platform(platform_lab, request) -> Iterator[Lab]:
    """The shared iot-platform lab, its world reset (cubes in the warehouse, arms home, belts stopped)."""
    with lend(platform_lab.get(), PLATFORM_LISTED, _world_reset) as lab:
        yield lab
    if _last_of_unit(request):
        platform_lab.close()


def _room_reset(lab: Lab) -> None:
    """The room as it starts: no obstacle, the simulation as fast as it goes, the world reset (cubes, belts,
    arms, pan-tilts), the lights off."""
    for obstacle in httpx.get(f"{lab.http}/world/properties/obstacles", timeout=30).json():
        r = httpx.post(f"{lab.http}/world/actions/removeObstacle", json={"name": obstacle["name"]}, timeout=120)
        assert r.status_code == 200, r.text
    assert httpx.put(f"{lab.http}/world/properties/speed", json=0, timeout=30).status_code == 204
    _world_reset(lab)
    _lights_off(lab)


@pytest.fixture(scope="session")
def iot_lab_shared(tmp_path_factory, tdgen_cache) -> Iterator[SharedLab]:
    """`twinmesh up --speed max --samples 4000` (the iot-lab) with the adapter and the session's tdgen cache."""
    shared = SharedLab(lambda: start_lab(tmp_path_factory.mktemp("shared-iot-lab"), None, http=True,
                                         things=set(IOT_LAB_THINGS),
                                         extra_args=("--speed", "max", "--samples", "4000", "--tdgen-cache",
                                                     str(tdgen_cache))),
                       "the shared iot-lab")
    yield shared
    shared.close()


@pytest.fixture(scope="module")
def iot_lab(iot_lab_shared, request) -> Iterator[Lab]:
    """The shared iot-lab, its room reset, for this module (which `SHARED_LAB` names)."""
    with lend(iot_lab_shared.get(), IOT_LAB_THINGS, _room_reset) as lab:
        yield lab
    if _last_of_unit(request):
        iot_lab_shared.close()


def pytest_sessionstart(session: pytest.Session) -> None:
    """Where the collision kernels are not compiled yet (a fresh machine, a fresh clone), the session compiles
    them once, from its start, at the tests' own priority: the labs it starts then find that compile under way
    and run uncompiled until it is done, as a first start does (`cores.compiled`), and the modules that run
    the kernels in the test process wait for it (`compiled_code`) instead of compiling them again beside it."""
    if hasattr(session.config, "workerinput"):  # an xdist worker: its controller started it
        return
    from tdgen.robot import cores

    if not cores.compiled():
        from tdgen.robot import fast_collision

        cores.compile_in_background(fast_collision, nice=0)


@pytest.fixture(scope="session")
def compiled_code() -> None:
    """The collision kernels compiled and loaded in this process: the session's compile awaited if it is under
    way (`pytest_sessionstart`), else compiled or loaded here."""
    from tdgen.robot.fast_collision import compile_all

    compile_all(wait=True)


def _cost(item: pytest.Item) -> int:
    """0: minutes on its own (`slow`); 1: a browser or node-wot; 2: a lab; 3: the kernels in the test process
    (`compiled_code`); 4: the unit layer."""
    marks = {mark.name for mark in item.iter_markers()}
    return 0 if "slow" in marks else 1 if marks & {"browser", "interop"} else 2 if "lab" in marks else 4


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The costliest modules first, each module whole and in its own order: xdist hands out units of work in
    collection order (`--no-loadscope-reorder`), so the long ones start at once and the unit layer fills the
    gaps at the end, instead of a module of minutes starting last beside an idle worker (xdist's own order,
    by test count, put test_wheel's two tests of minutes last). A module that runs the kernels in the test
    process goes after the labs, by when the session's compile is done (`pytest_sessionstart`)."""
    cost: dict[Path, int] = {}
    for item in items:
        cost[item.path] = min(cost.get(item.path, 4), _cost(item))
    for item in items:
        if "compiled_code" in getattr(item, "fixturenames", ()):
            cost[item.path] = max(cost[item.path], 3)
    items.sort(key=lambda item: cost[item.path])


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log):
    """`--dist loadfile`, with the modules of one `SHARED_LAB` entry as one unit of work."""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class ModulesAndSharedLabs(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            return SHARED_LAB.get(module, module)

    return ModulesAndSharedLabs(config, log)

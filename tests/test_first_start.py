"""The first start on a machine: where what is kept goes, what is compiled and when, what is said.

What a user would notice: files in their own cache and data directories (XDG's, on Linux), never in
site-packages; a first workspace as soon as pybullet can sample it, the same as any later one; an arm
that collides with its table in most poses reported as information, a likely mistake as a warning.
The first start's time is measured in tests/bench/bench_first_start.py.
"""
from __future__ import annotations

import importlib.util
import json
import logging
import os
import subprocess
import sys
import threading
import types
from pathlib import Path

import numpy as np
from waiting import eventually

from tdgen import sampling
from tdgen.generate import collision_warnings
from tdgen.robot import cores, fast_collision, kinematics, points_csv
from tdgen.robot.collision import CollisionWorld
from tdgen.robot.fast_collision import FastCollision
from tdgen.robot.kinematics import ForwardKinematics
from tdgen.robot.model import Robot
from tdgen.robot.surroundings import load_scene
from tdgen.sampling import Samples, random_configurations, sample_workspace

WHERE = """
import json, numba
from mesh.fabric.secrets import default_secrets_dir
from tdgen.robot import sphere_kernel
from tdgen.service import default_cache_dir
print(json.dumps({"tdgen": str(default_cache_dir()), "secrets": str(default_secrets_dir()),
                  "numba": numba.config.CACHE_DIR, "kernel": sphere_kernel.verdicts._cache.cache_path}))
"""


def _where(env: dict[str, str]) -> dict[str, str]:
    clean = {k: v for k, v in os.environ.items()
             if k not in ("TWINMESH_CACHE", "TWINMESH_SECRETS", "NUMBA_CACHE_DIR", "NUMBA_CACHE_LOCATOR_CLASSES",
                          "XDG_CACHE_HOME", "XDG_DATA_HOME")}
    out = subprocess.run([sys.executable, "-c", WHERE], env={**clean, **env}, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_caches_and_secrets_go_to_the_users_xdg_directories(tmp_path):
    where = _where({"XDG_CACHE_HOME": str(tmp_path / "cache"), "XDG_DATA_HOME": str(tmp_path / "data")})
    assert where["tdgen"] == str(tmp_path / "cache" / "twinmesh" / "tdgen")
    assert where["secrets"] == str(tmp_path / "data" / "twinmesh" / "secrets")
    assert where["numba"] == str(tmp_path / "cache" / "twinmesh" / "numba")
    assert where["kernel"].startswith(str(tmp_path / "cache" / "twinmesh" / "numba")), "compiled code beside the sources"


def test_twinmesh_cache_and_numba_cache_dir_still_win(tmp_path):
    where = _where({"XDG_CACHE_HOME": str(tmp_path / "cache"), "TWINMESH_CACHE": str(tmp_path / "mine"),
                    "NUMBA_CACHE_DIR": str(tmp_path / "numba")})
    assert where["tdgen"] == str(tmp_path / "mine" / "tdgen")
    assert where["numba"] == str(tmp_path / "numba")


def _cores_copied_elsewhere(monkeypatch, tmp_path: Path) -> types.ModuleType:
    """`cores` and our compiled modules copied to another folder and loaded from there, as a second install
    has them (numba's settings, which loading it sets, given back after the test)."""
    from numba.core import config

    monkeypatch.setattr(config, "CACHE_DIR", config.CACHE_DIR)
    monkeypatch.setattr(config, "CACHE_LOCATOR_CLASSES", config.CACHE_LOCATOR_CLASSES)
    copy_dir = tmp_path / "elsewhere" / "robot"
    copy_dir.mkdir(parents=True)
    for name in ("cores.py", *cores.COMPILED_MODULES):
        (copy_dir / name).write_bytes((Path(cores.__file__).parent / name).read_bytes())
    spec = importlib.util.spec_from_file_location("cores_elsewhere", copy_dir / "cores.py")
    elsewhere = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(elsewhere)
    return elsewhere


def test_the_same_code_in_another_place_finds_it_compiled_and_edited_code_compiles_afresh(monkeypatch, tmp_path):
    """Our compiled code is kept by what our compiled modules hold (`numba_locator`): a second install of the
    same version (another venv, a fresh clone) takes the first one's compile for its own; a copy with a
    compiled module edited does not (its every process would run stale code)."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba"))
    elsewhere = _cores_copied_elsewhere(monkeypatch, tmp_path)
    monkeypatch.setattr(cores, "_compiling_here", threading.Event())  # not this process's compile, whatever ran
    assert not cores.compiled() and not elsewhere.compiled()
    cores.compiled_stamp().parent.mkdir(parents=True)
    cores.compiled_stamp().touch()  # compiled here
    assert cores.compiled() and elsewhere.compiled(), "the same code elsewhere did not find its compile"
    kernel = tmp_path / "elsewhere" / "robot" / "sphere_kernel.py"
    kernel.write_text(kernel.read_text() + "\n# edited\n")
    elsewhere.sources_hash.cache_clear()
    assert not elsewhere.compiled(), "an edited copy took the compile of the code it was copied from"


def test_with_numbas_own_locators_chosen_a_copy_elsewhere_compiles_its_own(monkeypatch, tmp_path):
    """A user who sets NUMBA_CACHE_LOCATOR_CLASSES gets numba's own keeping, by folder: the same code
    elsewhere then has none of the first install's compile, so it must not take its stamp for its own."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba"))
    monkeypatch.setenv("NUMBA_CACHE_LOCATOR_CLASSES", "UserProvidedCacheLocator")
    elsewhere = _cores_copied_elsewhere(monkeypatch, tmp_path)
    monkeypatch.setattr(cores, "_compiling_here", threading.Event())
    cores.sources_hash.cache_clear()
    try:
        cores.compiled_stamp().parent.mkdir(parents=True)
        cores.compiled_stamp().touch()
        assert cores.compiled() and not elsewhere.compiled()
    finally:
        cores.sources_hash.cache_clear()  # the session's own environment again for the tests after


SECOND_INSTALL = """
import json, sys
import tdgen
from tdgen.robot import fast_collision, kinematics, points_csv, sphere_kernel
assert tdgen.__file__.startswith(sys.argv[1]), tdgen.__file__
fast_collision.compile_all()  # what the background compile runs: every compiled function, compiled or loaded
stats = {f"{m.__name__}.{name}": [sum(f.stats.cache_hits.values()), sum(f.stats.cache_misses.values())]
         for m in (sphere_kernel, points_csv, kinematics) for name, f in vars(m).items()
         if hasattr(f, "stats") and f.signatures}
print(json.dumps(stats))
"""


def test_a_second_install_of_the_same_code_loads_the_machines_compiled_code(compiled_code, tmp_path):
    """A fresh clone (the code copied elsewhere) runs everything a lab compiles from what this install
    compiled: every function from the cache, none compiled again, no folder of its own in the cache."""
    import hashlib
    import shutil

    from labs import REPO

    copy = tmp_path / "clone"
    for package in ("mesh", "tdgen"):
        shutil.copytree(REPO / package, copy / package, ignore=shutil.ignore_patterns("__pycache__"))
    done = subprocess.run([sys.executable, "-c", SECOND_INSTALL, str(copy)], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(copy)}, cwd=tmp_path, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    stats = json.loads(done.stdout.strip().splitlines()[-1])
    assert len(stats) >= 5, stats
    assert all(hits > 0 and misses == 0 for hits, misses in stats.values()), stats
    own = f"robot_{hashlib.sha1(str(copy / 'tdgen' / 'robot').encode()).hexdigest()}"  # numba's own name for it
    assert not (cores.compiled_code_dir() / own).exists()


def test_a_machine_without_the_compiled_model_gets_the_same_workspace_without_waiting_for_it(monkeypatch):
    """Not compiled yet: pybullet's exact test samples (the same flags, the same points to the micrometre)
    and the compiler is started once, in a process of its own."""
    robot, scene = Robot.load("ur10.urdf"), load_scene("table-and-wall")
    started = []
    monkeypatch.setattr(sampling, "compiled", lambda: False)
    monkeypatch.setattr(sampling, "compile_in_background", lambda module=None: started.append(module.__name__))
    cold = sample_workspace(robot, scene, 2500, seed=6, workers=1)
    assert started == ["tdgen.robot.fast_collision"]
    exact = sample_workspace(robot, scene, 2500, seed=6, workers=1, collision_model="exact")
    assert np.array_equal(cold.collision, exact.collision)
    assert np.abs(cold.positions - exact.positions).max() <= 0.001 + 1e-9  # mm


def test_a_planner_on_a_machine_without_the_compiled_model_answers_at_once_and_the_same(monkeypatch):
    """Not compiled yet: a robot's planner compiles nothing in its process (every Thing of the world process
    would wait for it): it gives the exact test's answers, the compiler started once elsewhere, and takes
    the compiled model once that is on disk, with the same answers."""
    robot, scene = Robot.load("ur10.urdf"), load_scene("table-and-wall")
    on_disk, started, sphere_calls = [False], [], []
    monkeypatch.setattr(fast_collision, "compiled", lambda: on_disk[0])
    monkeypatch.setattr(fast_collision, "compile_in_background", lambda module=None: started.append(module.__name__))
    monkeypatch.setattr(fast_collision, "LOOK_EVERY", 0.0)
    here = fast_collision.SphereModel.verdicts_here
    monkeypatch.setattr(fast_collision.SphereModel, "verdicts_here",
                        lambda self, *a, **k: sphere_calls.append(1) or here(self, *a, **k))
    q = random_configurations(robot, 60, 11)
    world, exact = CollisionWorld(robot, scene), CollisionWorld(robot, scene)
    try:
        expected = exact.colliding(q)
        assert 0 < expected.sum() < len(q), "the configurations are a mix of free and colliding ones"
        fast = FastCollision(world, warm=True)
        assert started == ["tdgen.robot.fast_collision"]
        assert [fast.collides(x) for x in q] == expected.tolist()
        assert np.array_equal(fast.colliding(q), expected)
        assert fast.first_collision(q[~expected]) is False and fast.first_collision(q) is True
        assert not fast.covering(q[:8], np.zeros(len(fast.grow_radii()[0]))).any()  # vouches for nothing
        assert sphere_calls == [] and fast.exact_only
        on_disk[0] = True  # the compiler is done
        assert [fast.collides(x) for x in q] == expected.tolist()
        assert sphere_calls and not fast.exact_only
        assert started == ["tdgen.robot.fast_collision"]
    finally:
        world.close()
        exact.close()


def test_a_first_starts_points_csv_is_the_same_file_without_the_compiled_formatter(monkeypatch):
    """Not compiled yet: points.csv is written without compiling its formatter, byte for byte the file the
    compiled one writes (rounding half to even at the last decimal, no `-0.000`)."""
    robot = Robot.load("ur10.urdf")
    rng = np.random.default_rng(5)
    q = random_configurations(robot, 3000, 5)
    positions = rng.uniform(-1500.0, 1500.0, (len(q), 3))
    positions[:40] = rng.integers(-3000, 3000, (40, 3)) / 2000.0  # ties at the last decimal: x.xxx5
    positions[40:50] = [-0.0004, -0.0005, 0.0]
    collision = rng.random(len(q)) < 0.4
    compiled_file = points_csv.encode(robot, positions, collision, q, compile_here=True)
    monkeypatch.setattr(points_csv, "compiled", lambda: False)
    assert points_csv.encode(robot, positions, collision, q) == compiled_file
    assert b"-0.000" not in compiled_file


def test_a_first_starts_kinematics_compile_nothing_and_answer_the_same(monkeypatch):
    """Not compiled yet: a robot's position and Jacobians (its Thing publishes the position at once) come
    from the walk's Python function, the same numbers, and the compiler is started elsewhere."""
    robot = Robot.load("ur10.urdf")
    q = random_configurations(robot, 50, 2)
    compiled_answer = ForwardKinematics(robot).poses_and_jacobians(q)
    started = []
    monkeypatch.setattr(kinematics, "compiled", lambda: False)
    monkeypatch.setattr(kinematics, "compile_in_background", lambda module=None: started.append(module))
    monkeypatch.setattr(kinematics, "_compiled_at", [0.0, 0.0])
    assert kinematics._chain_code() is kinematics._chain.py_func
    for compiled_part, python_part in zip(compiled_answer, ForwardKinematics(robot).poses_and_jacobians(q)):
        np.testing.assert_allclose(python_part, compiled_part, rtol=0, atol=1e-12)
    assert started == [None]  # the registered compiler: fast_collision, which kinematics does not import
    assert cores._compiler and cores._compiler[0].__name__ == "tdgen.robot.fast_collision"


DUMMY_COMPILE = """
import fcntl, json, os, sys
from tdgen.robot import cores
held = cores.LOCK_FD in os.environ
with open(cores.compiled_code_dir() / cores.COMPILING_LOCK, "w") as mine:  # a second lock on the file
    try:
        fcntl.flock(mine, fcntl.LOCK_EX | fcntl.LOCK_NB)
        held = False
    except BlockingIOError:
        pass
(cores.compiled_code_dir() / "ran.json").write_text(json.dumps({"niceness": os.nice(0), "held": held}))
"""


def test_the_background_compile_runs_once_at_low_priority_holding_the_lock(monkeypatch, tmp_path):
    """Two processes of a lab start it at once: one compile runs, niced, and holds the lock that keeps
    any other from starting (taken before it starts, so no race while it imports)."""
    (tmp_path / "dummy_compile.py").write_text(DUMMY_COMPILE)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba"))  # its own lock, whatever the session compiles
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(tmp_path), *sys.path]))
    monkeypatch.setattr(cores, "_started", threading.Event())
    cores.compile_in_background(types.ModuleType("dummy_compile"))  # run by name in the new process
    ran = cores.compiled_code_dir() / "ran.json"
    result = eventually(lambda: ran.exists() and json.loads(ran.read_text()), timeout=120, what="the compile's report")
    assert result == {"niceness": min(19, os.nice(0) + cores.BACKGROUND_NICE), "held": True}  # 19: the lowest


def _samples(robot: Robot, share: float) -> Samples:
    """Samples of which `share` are flagged colliding (the warnings' words depend on the flags and on what
    pybullet finds in the flagged ones)."""
    q = random_configurations(robot, 400, 3)
    collision = np.arange(len(q)) < share * len(q)
    return Samples(q, np.zeros((len(q), 3)), collision)


def test_an_arm_colliding_with_its_table_in_most_poses_is_information_not_a_warning(caplog):
    robot, scene = Robot.load("ur10.urdf"), load_scene("table-and-wall")
    with caplog.at_level(logging.INFO, logger="tdgen.generate"):
        warnings = collision_warnings(robot, scene, _samples(robot, 0.64))
    assert warnings == []
    said = [r for r in caplog.records if "64% of the samples collide" in r.getMessage()]
    assert said and said[0].levelno == logging.INFO


def test_a_scene_that_leaves_the_arm_little_room_is_a_warning():
    robot, scene = Robot.load("ur10.urdf"), load_scene("table-and-wall")
    warnings = collision_warnings(robot, scene, _samples(robot, 0.95))
    assert len(warnings) == 1 and warnings[0].startswith("95% of the samples collide")
    assert "little room" in warnings[0]


def test_an_arm_that_collides_at_rest_is_still_a_warning():
    """A start pose in collision: most likely collision meshes that overlap, said with the pairs."""
    robot, scene = Robot.load("ur10.urdf"), load_scene("table-and-wall")
    warnings = collision_warnings(robot, scene, _samples(robot, 0.64), at_rest=["base_link / shoulder_link"])
    assert warnings[0].startswith("64% of the samples collide")
    assert any("collides at rest" in w for w in warnings)

"""`twinmesh replay FILE.rrd`: a recording served to a browser on any host, or the desktop viewer.

The command's refusals run without a browser; the replay itself is checked over HTTP (the page, its
policy, the stream's port on loopback only) and then in headless Chromium: the recording drawn as
it was recorded, no Rerun error on the console, no request to any other host.
"""
import contextlib
import os
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import psutil
import pytest
from labs import REPO, free_port
from rerun_view import colour_share, viewer_page
from waiting import eventually

from mesh.messages.scene_description import Body, Pose, Poses, SceneDescription
from mesh.recorder.scene_drawer import SceneDrawer, SceneFiles, body_shape, lab_blueprint

MAGENTA = (255, 0, 255)
TWINMESH = str(Path(sys.executable).with_name("twinmesh"))


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """A small lab as the recorder draws it: a table, a lamp switched on in magenta, the lab's blueprint."""
    import rerun as rr

    path = tmp_path_factory.mktemp("replay") / "lamp.rrd"
    rec = rr.RecordingStream("twinmesh")
    rec.save(str(path))
    scene = SceneDescription("bench", bodies=[  # the lamp at the origin, where a scene without robots is looked at
        Body("table", "box", (0.4, 0.4, 0.1), Pose((0.0, 0.0, -0.15)), (0.55, 0.45, 0.35)),
        Body("lamp-shade", "box", (0.3, 0.3, 0.15), Pose((0.0, 0.0, 0.0)), (0.35, 0.35, 0.35), shows="lamp")])
    drawer = SceneDrawer(rec)
    drawer.draw_scene(SceneFiles(scene, {}), time.time(), 0)
    rec.set_time("sim_time", duration=1.0)
    for entry in drawer.add_poses(Poses(time=1.0, states={"lamp": {"on": True, "color": [1.0, 0.0, 1.0]}}),
                                  time.time(), 1):
        rec.log(entry.path, entry.archetype, static=entry.static)
    drawer.flush()
    rec.send_blueprint(lab_blueprint(scene, [], {}))
    rec.disconnect()
    return path


def replay(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([TWINMESH, "replay", *args], capture_output=True, text=True, timeout=120, cwd=REPO,
                          env={**os.environ, **(env or {})})


def test_a_missing_file_is_named_with_exit_2(tmp_path):
    r = replay(str(tmp_path / "nothing.rrd"))
    assert r.returncode == 2 and "nothing.rrd: no such file" in r.stderr and "Traceback" not in r.stderr


def test_a_file_that_is_not_a_recording_is_refused_with_exit_2(tmp_path):
    (tmp_path / "notes.rrd").write_text("hello")
    r = replay(str(tmp_path / "notes.rrd"))
    assert r.returncode == 2 and "is not a Rerun recording" in r.stderr and "Traceback" not in r.stderr


def test_the_desktop_viewer_without_a_display_says_what_to_do_instead(recording):
    r = replay(str(recording), "--desktop", env={"DISPLAY": "", "WAYLAND_DISPLAY": ""})
    assert r.returncode == 2 and "DISPLAY is not set" in r.stderr and "without --desktop" in r.stderr


def test_a_port_in_use_is_named(recording):
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        r = replay(str(recording), "--port", str(port))
    assert r.returncode == 2 and f"port {port} on 127.0.0.1 is taken (--port)" in r.stderr


class Replaying:
    """`twinmesh replay` running in the background; `url` is what it printed."""

    def __init__(self, path: Path, tmp: Path, background: bool = False):
        """`background`: started as a script's `cmd &` starts it, SIGINT ignored from the start."""
        self.port = free_port()
        self.log = tmp / "replay.log"
        ignore = (lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)) if background else None
        self.proc = subprocess.Popen([TWINMESH, "replay", str(path), "--port", str(self.port),
                                      "--grpc-port", str(free_port())],
                                     stdout=open(self.log, "wb"), stderr=subprocess.STDOUT, cwd=REPO,
                                     preexec_fn=ignore)
        line = eventually(lambda: self._said("replaying "), timeout=120, what="the replay's URL")
        self.url = line.split(" at ", 1)[1].split()[0]

    def _said(self, text: str) -> str | None:
        assert self.proc.poll() is None, self.log.read_text()
        return next((line for line in self.log.read_text().splitlines() if line.startswith(text)), None)

    def stop(self) -> int:
        self.proc.send_signal(signal.SIGINT)
        try:
            return self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:  # where it is stuck, from its threads' stacks, in the failure
            self.proc.send_signal(signal.SIGUSR1)
            try:
                eventually(lambda: "Thread 0x" in self.log.read_text(errors="replace"), timeout=10,
                           what="its threads' stacks in its log")
            finally:  # the replay and the viewer's server it started in a session of its own: none left behind
                for process in [*psutil.Process(self.proc.pid).children(recursive=True), self.proc]:
                    with contextlib.suppress(psutil.Error, ProcessLookupError):
                        process.kill()
                self.proc.wait()
            raise AssertionError("twinmesh replay did not stop within 30 s of Ctrl-C:\n"
                                 + self.log.read_text(errors="replace")[-6000:]) from None


@pytest.fixture
def replaying(recording, tmp_path):
    r = Replaying(recording, tmp_path)
    yield r
    if r.proc.poll() is None:
        r.stop()


def test_the_replay_page_is_served_on_loopback_with_a_policy_that_keeps_it_here(replaying):
    assert replaying.url.startswith(f"http://127.0.0.1:{replaying.port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A")
    with urllib.request.urlopen(replaying.url, timeout=60) as page:
        policy = page.headers["Content-Security-Policy"]
        body = page.read().decode()
    assert "connect-src 'self' http://*:" in policy and "default-src 'self'" in policy
    assert 'src = "viewer.html"' in body  # our page, holding Rerun's in a frame
    viewer = replaying.url.split("?")[0] + "viewer.html"
    with urllib.request.urlopen(viewer, timeout=60) as page:
        assert page.headers["Content-Security-Policy"] == policy
        body = page.read().decode()
    assert "re_viewer" in body  # Rerun's own page
    assert "fonts.googleapis.com" not in body  # its web-font links are taken out
    assert replaying.stop() in (0, -2, 130)


def test_ctrl_c_stops_a_replay_that_a_script_started_in_the_background(recording, tmp_path):
    replaying = Replaying(recording, tmp_path, background=True)
    try:
        assert replaying.stop() in (0, -2, 130)
    finally:
        if replaying.proc.poll() is None:
            replaying.proc.kill()


@pytest.mark.browser
@pytest.mark.slow
@pytest.mark.timeout(1200)  # a software rasteriser on a busy machine needs minutes for its first frame
def test_a_replay_draws_the_recording_in_the_browser_and_asks_no_other_host(replaying):
    with viewer_page(replaying.url) as view:
        eventually(lambda: colour_share(view.pixels(), MAGENTA) > 0.001, timeout=900, interval=5.0,
                   what="the magenta lamp of the recording in the view")
        assert view.rerun_problems() == []
        assert view.foreign_hosts() == set()


# --- moving things placed by rows that name their frames, drawn as Rerun draws one entity per frame ----
UR10_URDF = (REPO / "tdgen" / "robot" / "models" / "ur10.urdf").read_text()
UR10_POSE = {"shoulder_pan_joint": 1.2, "shoulder_lift_joint": -1.0, "elbow_joint": 1.5, "wrist_1_joint": 0.8,
             "wrist_2_joint": 0.0, "wrist_3_joint": 0.0}  # rad: far from the zero pose
CUBE = Body("cube", "box", (0.2, 0.2, 0.2), Pose((0.5, 0.5, 0.1)), (0.9, 0.1, 0.1), moving=True)
CUBE_MOVED = Pose((0.4, -0.4, 0.3))


def ur10_recording(path: Path, pose: dict[str, float], cube: Pose, one_entity_each: bool = False) -> Path:
    """A UR10 in `pose` and a cube moved to `cube`, as the recorder draws them (the robot's moved joints
    as rows of one entity, the cube's pose a row of `world/poses`), or, `one_entity_each`, each joint's
    transform and the cube's pose logged on an entity of its own, as Rerun's docs do."""
    import rerun as rr

    from mesh.messages.scene_description import RobotModel

    rec = rr.RecordingStream("twinmesh")
    rec.save(str(path))
    scene = SceneDescription("ur10", robots=[RobotModel("ur10", "ur10.urdf", Pose((0.0, 0.0, 0.0)))],
                             bodies=[] if one_entity_each else [CUBE])
    drawer = SceneDrawer(rec)
    assert drawer.draw_scene(SceneFiles(scene, {"ur10.urdf": UR10_URDF}), time.time(), 0) == []
    if one_entity_each:
        rec.set_time("sim_time", duration=1.0)
        robot = drawer.robots["ur10"]
        for joint, value in pose.items():
            rec.log(f"reference/{joint}", robot.joints[joint].compute_transform(value, clamp=False))
        rec.log("world/bodies/cube", body_shape(CUBE), static=True)
        rec.log("world/bodies/cube", rr.Transform3D(translation=cube.p, quaternion=rr.Quaternion(xyzw=cube.q)))
    else:
        drawer.add_poses(Poses(time=1.0, joints={"ur10": pose}, bodies={"cube": cube}), time.time(), 1)
        drawer.flush()
    rec.send_blueprint(lab_blueprint(scene, ["ur10"], {}))
    rec.disconnect()
    return path


def settled_view(path: Path, tmp: Path) -> np.ndarray:
    """The 3D view of a replayed recording once it stops changing, with no Rerun error on the page."""
    replaying = Replaying(path, tmp)
    try:
        with viewer_page(replaying.url) as view:
            last: list[np.ndarray] = []

            def settled() -> tuple[np.ndarray] | None:
                pixels = view.view_pixels().astype(int)
                same = len(last) >= 2 and all(np.abs(pixels - p).max() <= 2 for p in last[-2:])
                last.append(pixels)
                return (pixels,) if same and pixels.std() > 10 else None

            pixels = eventually(settled, timeout=600, interval=3.0, what=f"the view of {path.name} settled")[0]
            assert view.rerun_problems() == []
    finally:
        replaying.stop()
    return pixels


def differing(a: np.ndarray, b: np.ndarray) -> float:
    return float((np.abs(a - b).max(axis=2) > 30).mean())


@pytest.mark.browser
@pytest.mark.slow
@pytest.mark.timeout(2400)
def test_a_robot_and_a_cube_placed_by_rows_naming_their_frames_stand_as_drawn_one_entity_each(tmp_path):
    posed = settled_view(ur10_recording(tmp_path / "posed.rrd", UR10_POSE, CUBE_MOVED), tmp_path)
    reference = settled_view(ur10_recording(tmp_path / "reference.rrd", UR10_POSE, CUBE_MOVED, one_entity_each=True),
                             tmp_path)
    still = settled_view(ur10_recording(tmp_path / "still.rrd", dict.fromkeys(UR10_POSE, 0.0), CUBE.pose), tmp_path)
    assert differing(posed, still) > 0.05, "the moves are not seen: the test would not tell things left where they were"
    assert differing(posed, reference) < 0.005

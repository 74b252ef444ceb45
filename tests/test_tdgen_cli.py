"""`tdgen` and `check` commands: outputs, exit codes, and clear messages for malformed inputs."""
from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from devices.cli.main import main

NO_JOINT_URDF = """<robot name="statue">
  <link name="base"><collision><geometry><box size="0.1 0.1 0.1"/></geometry></collision></link>
  <link name="head"/>
  <joint name="neck" type="fixed"><parent link="base"/><child link="head"/></joint>
</robot>"""


def _run(*args: str):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def td_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "xarm"
    result = _run("tdgen", "xarm/xarm6_robot.urdf", "--scene", "table-and-wall", "--samples", 3000, "--seed", 1,
                  "--out", out, "--workers", 1, "--concave", "--base-url", "http://lab.example/things/xarm/",
                  "--security", "bearer", "--id", "urn:uuid:8a0c5f4e-2c1b-4d7e-9a51-0f3c2b1d4e6a")
    assert result.exit_code == 0, result.output
    return out, result.output


def test_tdgen_writes_the_td_and_its_artefacts(td_dir):
    out, output = td_dir
    names = {p.name for p in out.iterdir()}
    assert names == {"td.json", "robot-info.json", "points.csv", "workspace.stl", "workspace-concave.stl",
                     "scene.json"}
    td = json.loads((out / "td.json").read_text())
    assert (td["title"], td["id"]) == ("xarm", "urn:uuid:8a0c5f4e-2c1b-4d7e-9a51-0f3c2b1d4e6a")  # the URL's Thing
    assert td["properties"]["getJointposition"]["forms"][0]["href"] == \
        "http://lab.example/things/xarm/properties/getJointposition"
    assert td["security"] == ["bearer_sc"] and td["securityDefinitions"]["bearer_sc"]["scheme"] == "bearer"
    assert "workspace hull:" in output and "alpha shape:" in output and "3000 samples" in output


def test_check_exits_0_for_a_good_target_and_1_with_the_reason_for_a_bad_one(td_dir):
    out, _ = td_dir
    ok = _run("check", out, 300, -200, 300, "--radius", 150)
    assert ok.exit_code == 0, ok.output
    assert "OK:" in ok.output
    far = _run("check", out, -5000, 0, 0)                   # negative coordinates are numbers, not options
    assert far.exit_code == 1
    assert "REFUSED: outside the workspace hull" in far.output


def test_check_of_a_directory_without_points_says_so(tmp_path):
    result = _run("check", tmp_path, 0, 0, 0)
    assert result.exit_code == 2 and "no points.csv" in result.output and "Traceback" not in result.output


def _broken(tmp_path):
    (tmp_path / "broken.urdf").write_text("<robot name='x'><link name='a'>")
    (tmp_path / "statue.urdf").write_text(NO_JOINT_URDF)
    (tmp_path / "scene.json").write_text('{"name": "s", "bodies": [{"type": "box", "size": [1, 1]}]}')
    (tmp_path / "one.csv").write_text("twin_x,twin_y,twin_z,real_x,real_y,real_z\n1,2,3,4,5,6\n")
    return tmp_path


@pytest.mark.parametrize("args, problem", [
    (["missing.urdf"], "missing.urdf: URDF file not found"),
    (["{d}/broken.urdf"], "broken XML"),
    (["{d}/statue.urdf"], "no actuated joint"),
    (["ur10.urdf", "--scene", "{d}/scene.json"], "scene.json: not a valid scene"),
    (["ur10.urdf", "--scene", "no-such-scene"], "scene file not found"),
    (["ur10.urdf", "--calibration", "{d}/one.csv"], "1 pair given: calibration needs at least two"),
    (["ur10.urdf", "--frame", "real"], "real frame needs a calibration"),
    (["ur10.urdf", "--ee", "no_link"], "no link named 'no_link'"),
    (["ur10.urdf", "--base-url", "http://127.0.0.1:8080/"], "--base-url must be the Thing's URL on the adapter"),
    (["ur10.urdf", "--base-url", "http://127.0.0.1:8080/ur10", "--name", "arm"], "names the Thing 'ur10', not 'arm'"),
])
def test_malformed_inputs_fail_with_a_message_naming_the_problem(tmp_path, args, problem):
    d = _broken(tmp_path)
    result = _run("tdgen", *[a.format(d=d) for a in args], "--samples", 10, "--out", tmp_path / "out")
    assert result.exit_code != 0
    assert problem in result.output
    assert "Traceback" not in result.output and isinstance(result.exception, SystemExit)
    assert not (tmp_path / "out").exists()  # checked before any sampling or writing


def test_a_scene_urdf_pybullet_cannot_load_fails_cleanly_with_several_workers(tmp_path):
    (tmp_path / "junk.urdf").write_text("<robot name='junk'><link name='a'>")
    (tmp_path / "scene.json").write_text('{"name": "s", "bodies": [{"type": "urdf", "urdf": "junk.urdf"}]}')
    result = _run("tdgen", "ur10.urdf", "--scene", tmp_path / "scene.json", "--samples", 2500, "--workers", 2,
                  "--out", tmp_path / "out")
    assert result.exit_code != 0
    assert "pybullet cannot load" in result.output and "junk.urdf" in result.output
    assert "Traceback" not in result.output


def test_a_piped_csv_holds_only_csv_and_pybullet_speaks_on_stderr_with_v(tmp_path):
    """pybullet's C prints (`pybullet build time`, `b3Warning`...) go to descriptor 1 past Python: they
    must not land in what `twinmesh ik --targets` writes to a pipe; `-v` shows them on stderr."""
    import subprocess
    import sys

    targets = tmp_path / "targets.csv"
    targets.write_text("300,0,400\n200,100,300\n")
    command = [sys.executable, "-m", "devices", "ik", "xarm/xarm6_robot.urdf", "--targets", str(targets)]
    quiet = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert quiet.returncode == 0, quiet.stderr
    header, *rows = quiet.stdout.splitlines()
    assert header.startswith("x,y,z,reached_x,reached_y,reached_z,error_mm,") and len(rows) == 2
    assert all(float(v) == float(v) for row in rows for v in row.split(","))  # numbers only
    assert "pybullet" not in quiet.stdout + quiet.stderr and "b3" not in quiet.stdout
    loud = subprocess.run([sys.executable, "-m", "devices", "-v", *command[3:]], capture_output=True, text=True,
                          timeout=120)
    assert loud.stdout == quiet.stdout and "pybullet build time" in loud.stderr


def test_a_ceiling_mount_given_as_tilt_or_as_quaternion_is_the_same_mount(tmp_path):
    common = ["tdgen", "ur10.urdf", "--samples", 800, "--workers", 1, "--no-progress"]
    tilt = _run(*common, "--out", tmp_path / "tilt", "--base", 0, 0, 2.5, 0, "--base-tilt", 180, 0)
    quat = _run(*common, "--out", tmp_path / "quat", "--base", 0, 0, 2.5, 0, "--base-quat", 1, 0, 0, 0)
    assert tilt.exit_code == 0 and quat.exit_code == 0, tilt.output + quat.output
    scenes = [json.loads((tmp_path / d / "scene.json").read_text()) for d in ("tilt", "quat")]
    assert scenes[0] == scenes[1] and scenes[0]["robot"]["roll"] == 180.0
    assert (tmp_path / "tilt" / "points.csv").read_text() == (tmp_path / "quat" / "points.csv").read_text()
    both = _run(*common, "--out", tmp_path / "x", "--base-tilt", 90, 0, "--base-quat", 0, 0, 0, 1)
    assert both.exit_code == 2 and "--base-quat gives the whole orientation" in both.output


def test_stderr_carries_only_twinmesh_s_own_lines_with_two_workers(tmp_path):
    """pybullet's banner was printed once per worker process; a xacro error was said twice."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "devices", "tdgen", "ur10.urdf", "--samples", "2000", "--workers", "2",
                           "--no-progress", "--out", str(tmp_path / "out")], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "pybullet" not in done.stderr and "b3Warning" not in done.stderr, done.stderr
    xacro = tmp_path / "bad.urdf.xacro"
    xacro.write_text('<?xml version="1.0"?><robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="bad">'
                     '<xacro:include filename="$(find nosuch_description)/urdf/arm.xacro"/><link name="base"/></robot>')
    failed = subprocess.run([sys.executable, "-m", "devices", "tdgen", str(xacro), "--out", str(tmp_path / "x")],
                            capture_output=True, text=True, timeout=120)
    assert failed.returncode == 2
    lines = failed.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].count("$(find nosuch_description)") == 1, failed.stderr  # said once
    assert str(xacro) in lines[0] and "looked in" in lines[0] and "twinmesh-urdf" not in lines[0]


def test_samples_are_taken_as_people_write_them_and_a_fraction_is_refused(tmp_path):
    written = _run("tdgen", "ur10.urdf", "--samples", "2e3", "--no-progress", "--out", tmp_path / "a")
    assert written.exit_code == 0, written.output
    assert "ur10: 2000 samples" in written.output
    assert len((tmp_path / "a" / "points.csv").read_text().splitlines()) == 2001  # the header and 2,000 points
    for bad, why in (("2.5", "not a whole number"), ("lots", "not a number of samples"), ("0", "below")):
        refused = _run("tdgen", "ur10.urdf", "--samples", bad, "--out", tmp_path / "b")
        assert refused.exit_code == 2 and why in refused.output, refused.output
    assert not (tmp_path / "b").exists()

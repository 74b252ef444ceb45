"""URDF files as they come: prefixes urdfdom ignores, `package://` meshes resolved as ROS does, a missing
mesh named with where it was looked for, and the arm chain chosen from a gripper-carrying tree."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from tdgen.generate import generate
from tdgen.robot.kinematics import ForwardKinematics
from tdgen.robot.model import ROBOTS_DIR, Robot, RobotError

LINK = '<link name="{0}"><collision><geometry>{1}</geometry></collision></link>'
BOX = '<box size="0.04 0.04 0.2"/>'
JOINT = ('<joint name="{0}" type="{1}" {4}><parent link="{2}"/><child link="{3}"/><origin xyz="0 0 0.2"/>'
         '<axis xyz="0 1 0"/><limit lower="-1.5" upper="1.5" effort="1" velocity="1"/>{5}</joint>')


def arm_urdf(tmp_path: Path, geometry: str = BOX, extra: str = "", name: str = "arm.urdf") -> Path:
    """Three arm joints, then a gripper: a prismatic finger joint and its mimic twin."""
    links = "".join(LINK.format(n, geometry) for n in ["base", "l1", "l2", "l3", "palm", "finger_a", "finger_b"])
    joints = [JOINT.format("j1", "revolute", "base", "l1", extra, ""),
              JOINT.format("j2", "revolute", "l1", "l2", "", ""),
              JOINT.format("j3", "revolute", "l2", "l3", "", ""),
              '<joint name="palm_mount" type="fixed"><parent link="l3"/><child link="palm"/></joint>',
              JOINT.format("finger_joint_a", "prismatic", "palm", "finger_a", "", ""),
              JOINT.format("finger_joint_b", "prismatic", "palm", "finger_b", "",
                           '<mimic joint="finger_joint_a" multiplier="-1"/>')]
    path = tmp_path / name
    path.write_text(f'<?xml version="1.0"?><robot name="arm">{links}{"".join(joints)}</robot>')
    return path


def test_the_chain_stops_before_the_gripper_and_follows_the_fixed_palm(tmp_path):
    robot = Robot.load(arm_urdf(tmp_path))
    assert [j.name for j in robot.joints] == ["j1", "j2", "j3"] and robot.ee_link == "palm"
    assert "arm chain base -> palm: 3 joints" in robot.describe_chain()


def test_a_held_joint_is_not_moved_and_its_value_is_in_the_kinematics(tmp_path):
    free = Robot.load(arm_urdf(tmp_path))
    held = Robot.load(arm_urdf(tmp_path), fixed={"j1": 30.0})  # deg
    assert [j.name for j in held.joints] == ["j2", "j3"]
    q = np.array([[0.2, -0.4]])
    expected = ForwardKinematics(free).positions(np.array([[np.radians(30.0), 0.2, -0.4]]))
    assert np.allclose(ForwardKinematics(held).positions(q), expected, atol=1e-12)
    with pytest.raises(RobotError, match="cannot hold nope: not movable joints"):
        Robot.load(arm_urdf(tmp_path), fixed={"nope": 1.0})


def test_a_base_link_starts_the_chain_and_holds_what_is_above(tmp_path):
    robot = Robot.load(arm_urdf(tmp_path), base_link="l1")
    assert [j.name for j in robot.joints] == ["j2", "j3"] and robot.held == {"j1": 0.0}
    with pytest.raises(RobotError, match="'base' is not below the base link 'l2'"):
        Robot.load(arm_urdf(tmp_path), base_link="l2", ee="base")


def test_attributes_in_prefixes_nobody_declared_are_ignored_as_urdfdom_does(tmp_path):
    text = (ROBOTS_DIR / "ur10.urdf").read_text().replace('<joint name="shoulder_pan_joint"',
                                                            '<joint drake:acceleration="12" name="shoulder_pan_joint"')
    assert "drake:" in text
    path = tmp_path / "ur10-drake.urdf"
    path.write_text(text)
    robot = Robot.load(path)
    assert len(robot.joints) == 6 and robot.load_path != path  # pybullet loads a copy with the prefix declared


def _mesh_package(tmp_path: Path) -> tuple[Path, str]:
    package = tmp_path / "packages" / "my_arm_description"
    (package / "meshes").mkdir(parents=True)
    trimesh.creation.box((0.04, 0.04, 0.2)).export(package / "meshes" / "link.stl")
    return package, '<mesh filename="package://my_arm_description/meshes/link.stl"/>'


def test_package_meshes_are_found_where_they_are_named(tmp_path, monkeypatch):
    package, mesh = _mesh_package(tmp_path)
    (tmp_path / "elsewhere").mkdir()  # not below the package: pybullet's upward search cannot find it
    urdf = arm_urdf(tmp_path / "elsewhere", mesh)
    robot = Robot.load(urdf, packages={"my_arm_description": package})
    assert robot.load_path is not None and str(package / "meshes" / "link.stl") in robot.load_path.read_text()
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(package.parent))  # as ROS 1 finds it
    assert Robot.load(urdf).ee_link == "palm"
    monkeypatch.delenv("ROS_PACKAGE_PATH")
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path / "prefix"))  # ROS 2: <prefix>/share/<package>
    (tmp_path / "prefix" / "share").mkdir(parents=True)
    (tmp_path / "prefix" / "share" / "my_arm_description").symlink_to(package)
    assert Robot.load(urdf).ee_link == "palm"


def test_a_missing_mesh_is_named_with_where_it_was_looked_for(tmp_path):
    _, mesh = _mesh_package(tmp_path)
    (tmp_path / "elsewhere").mkdir()
    urdf = arm_urdf(tmp_path / "elsewhere", mesh)
    with pytest.raises(RobotError) as err:
        Robot.load(urdf)
    message = str(err.value)
    assert "mesh package://my_arm_description/meshes/link.stl not found (looked in" in message
    assert "--package-path NAME=DIR" in message and "Cannot load URDF" not in message


XACRO = """<?xml version="1.0"?>
<robot name="macro_arm" xmlns:xacro="http://www.ros.org/wiki/xacro">
  <xacro:property name="length" value="0.2"/>
  <xacro:macro name="segment" params="n parent">
    <link name="l${n}"><collision><geometry>
      <mesh filename="file://$(find my_arm_description)/meshes/link.stl"/></geometry></collision></link>
    <joint name="j${n}" type="revolute"><parent link="${parent}"/><child link="l${n}"/>
      <origin xyz="0 0 ${length}"/><axis xyz="0 1 0"/><limit lower="-1.5" upper="1.5" effort="1" velocity="1"/>
    </joint>
  </xacro:macro>
  <link name="base"/>
  <xacro:segment n="1" parent="base"/>
  <xacro:segment n="2" parent="l1"/>
  <xacro:segment n="3" parent="l2"/>
</robot>
"""


def test_a_xacro_file_is_expanded_with_its_packages_found_as_for_meshes(tmp_path):
    pytest.importorskip("xacro", reason="xacro is a test extra (pip install -e '.[test]')")
    package, _ = _mesh_package(tmp_path)
    (tmp_path / "elsewhere").mkdir()
    path = tmp_path / "elsewhere" / "macro_arm.urdf.xacro"
    path.write_text(XACRO)
    with pytest.raises(RobotError, match=r"\$\(find my_arm_description\): no package 'my_arm_description'"):
        Robot.load(path)
    robot = Robot.load(path, packages={"my_arm_description": package})
    assert [j.name for j in robot.joints] == ["j1", "j2", "j3"] and robot.urdf_path.name == "macro_arm.urdf"
    assert str(package / "meshes" / "link.stl") in robot.urdf_path.read_text()


@pytest.mark.parametrize("arm", ["ur5e", "ur3e"])
def test_airo_models_urs_with_drake_attributes_load_as_they_come(arm):
    """airo-models ships UR URDFs with `drake:` attributes (no namespace declared), which an XML parser
    refuses and urdfdom and pybullet ignore: they load, the right chain, meshes found."""
    airo_models = pytest.importorskip("airo_models", reason="airo-models is a test extra")
    path = Path(airo_models.__file__).parent / "arms" / arm / f"{arm}.urdf"
    assert "drake:" in path.read_text()
    robot = Robot.load(path)
    assert (robot.base_link, robot.ee_link, len(robot.joints)) == ("base_link", "tool0", 6)


def _mesh_arm(folder: Path, uri: str) -> Path:
    """A three-joint arm whose links are a mesh file named by `uri`, in `folder`."""
    return arm_urdf(folder, geometry=f'<mesh filename="{uri}"/>')


def test_relative_file_uris_are_the_urdfs_folder_whatever_the_current_directory(tmp_path, monkeypatch):
    robot_dir = tmp_path / "robot"
    (robot_dir / "meshes" / "visual").mkdir(parents=True)
    trimesh.creation.box((0.04, 0.04, 0.2)).export(robot_dir / "meshes" / "visual" / "link.stl")
    urdf = _mesh_arm(robot_dir, "file://meshes/visual/link.stl")
    elsewhere = tmp_path / "elsewhere"
    (elsewhere / "meshes" / "visual").mkdir(parents=True)
    trimesh.creation.box((1, 1, 1)).export(elsewhere / "meshes" / "visual" / "link.stl")  # a decoy, 1 m
    loaded = []
    for cwd in (robot_dir, elsewhere, tmp_path):
        monkeypatch.chdir(cwd)
        robot = Robot.load(urdf)
        loaded.append(robot.load_path.read_text())
    assert loaded[0] == loaded[1] == loaded[2]
    assert str(robot_dir / "meshes" / "visual" / "link.stl") in loaded[0] and str(elsewhere) not in loaded[0]


def test_a_ros_package_path_entry_is_never_taken_for_a_package_it_is_not(tmp_path, monkeypatch):
    root = tmp_path / "ws"
    described = root / "src" / "description_folder"  # found by its package.xml's name, two levels down
    (described / "meshes").mkdir(parents=True)
    (described / "package.xml").write_text("<package><name>my_arm_description</name></package>")
    trimesh.creation.box((0.04, 0.04, 0.2)).export(described / "meshes" / "link.stl")
    (root / "meshes").mkdir()
    trimesh.creation.box((1, 1, 1)).export(root / "meshes" / "link.stl")  # what the old lookup took
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(root))
    monkeypatch.delenv("AMENT_PREFIX_PATH", raising=False)
    found = Robot.load(_mesh_arm(tmp_path, "package://my_arm_description/meshes/link.stl"))
    assert str(described / "meshes" / "link.stl") in found.load_path.read_text()
    with pytest.raises(RobotError, match="package://other_description/meshes/link.stl not found"):
        Robot.load(_mesh_arm(tmp_path, "package://other_description/meshes/link.stl"), )


def _arm_with_frames(tmp_path: Path, frames: dict[str, str]) -> Path:
    """The arm without its gripper, its last link carrying fixed frames at the given offsets ("x y z", m)."""
    links = "".join(LINK.format(n, BOX) for n in ["base", "l1", "l2", "l3"]) + "".join(
        f'<link name="{n}"/>' for n in frames)
    joints = [JOINT.format("j1", "revolute", "base", "l1", "", ""), JOINT.format("j2", "revolute", "l1", "l2", "", ""),
              JOINT.format("j3", "revolute", "l2", "l3", "", "")]
    joints += [f'<joint name="{n}_mount" type="fixed"><parent link="l3"/><child link="{n}"/>'
               f'<origin xyz="{xyz}"/></joint>' for n, xyz in frames.items()]
    path = tmp_path / "frames.urdf"
    path.write_text(f'<?xml version="1.0"?><robot name="arm">{links}{"".join(joints)}</robot>')
    return path


def test_the_tip_is_the_most_distal_frame_through_fixed_joints_a_tool_frame_first(tmp_path):
    """A Panda's last link carries a flange and an end-effector frame: the tip used to stop before both."""
    def tip(frames: dict[str, str], **options) -> str:
        return Robot.load(_arm_with_frames(tmp_path, frames), **options).ee_link

    assert tip({"link8": "0 0 0.107", "end_effector_frame": "0 0 0.21"}) == "end_effector_frame"
    assert tip({"panda_flange": "0 0 0.107", "tool_frame": "0 0 0.3"}) == "tool_frame"
    assert tip({"ee_link": "0 0.08 0", "tool0": "0 0.08 0"}) == "ee_link"  # one place: one tip (a UR's)
    assert tip({"left_pad_mount": "0 0.02 0.1", "right_pad_mount": "0 -0.02 0.1"}) == "l3"  # a tool's own parts
    with pytest.raises(RobotError, match=r"ends in 2 tool frames equally far apart \(tool_a, tool_b\): pick the tip "
                                         r"with --ee LINK"):
        tip({"tool_a": "0.1 0 0", "tool_b": "0 0 0.1"})
    assert tip({"tool_a": "0.1 0 0", "tool_b": "0 0 0.1"}, ee="tool_b") == "tool_b"


def test_the_chosen_base_and_tip_are_said_on_stderr(tmp_path):
    from click.testing import CliRunner

    from devices.cli.main import main

    urdf = _arm_with_frames(tmp_path, {"flange": "0 0 0.1", "end_effector_frame": "0 0 0.2"})
    result = CliRunner().invoke(main, ["tdgen", str(urdf), "--tip", "flange", "--samples", "500", "--workers", "1",
                                       "--no-progress", "--out", str(tmp_path / "out")])
    assert "arm chain base -> flange" in result.stderr and "arm chain" not in result.stdout, result.output


def _visual_only_arm(tmp_path: Path, geometry: str) -> Path:
    """The arm with every link's geometry as a visual only (as hobby and classic arms often ship)."""
    text = arm_urdf(tmp_path, geometry=geometry).read_text().replace("<collision>", "<visual>").replace(
        "</collision>", "</visual>").replace('<axis xyz="0 1 0"/>', '<axis xyz="0 0 1"/>', 1).replace(
        'lower="-1.5" upper="1.5"', 'lower="-3" upper="3"')  # not planar, and it can fold into the floor
    path = tmp_path / "visual_only.urdf"
    path.write_text(text)
    return path


def test_links_without_collision_geometry_collide_with_their_visual_one_and_say_so(tmp_path):
    from tdgen.generate import generate
    from tdgen.robot.points_csv import read as read_points_csv

    mesh_dir = tmp_path / "meshes"
    mesh_dir.mkdir()
    trimesh.creation.box((0.04, 0.04, 0.2)).export(mesh_dir / "link.stl")
    robot = Robot.load(_visual_only_arm(tmp_path, '<mesh filename="meshes/link.stl"/>'))
    assert set(robot.visual_collisions) == {"base", "l1", "l2", "l3", "palm", "finger_a", "finger_b"}
    assert robot.notes() == ["7 link(s) have no collision geometry; their visual geometry is used for collision: "
                             "base, l1, l2, l3, palm, finger_a, finger_b"]
    positions, collision = read_points_csv(generate(robot, None, 1500, seed=1, out_dir=tmp_path / "out",
                                                    workers=1).files["points"])
    assert collision.any(), "the arm went through the floor and itself unseen"
    assert positions[~collision][:, 2].min() >= -1.0  # mm: nothing free under the floor


def test_a_urdf_without_any_geometry_is_refused_not_all_free(tmp_path):
    bare = arm_urdf(tmp_path).read_text()
    import re

    path = tmp_path / "bare.urdf"
    path.write_text(re.sub(r"<collision>.*?</collision>", "", bare))
    robot = Robot.load(path)  # kinematics and IK need no geometry: it loads
    assert robot.ee_link
    with pytest.raises(RobotError, match=r"bare\.urdf: no link has collision or visual geometry"):
        generate(robot, None, 300, seed=0, out_dir=tmp_path / "out", workers=1)


def test_a_start_pose_touching_the_mounting_surface_names_the_pair_and_allowing_it_works(tmp_path):
    """A Panda variant's link1 collision sphere reaches below its base: the refusal suggested --no-surface
    (for a "humanoid"), and --allow-collision panda_link1/mounting-surface was refused."""
    from click.testing import CliRunner

    from devices.cli.main import main

    text = arm_urdf(tmp_path).read_text().replace('<axis xyz="0 1 0"/>', '<axis xyz="0 0 1"/>', 1).replace(
        '<link name="l1"><collision><geometry><box size="0.04 0.04 0.2"/></geometry></collision></link>',
        '<link name="l1"><collision><origin xyz="0 0 -0.2"/><geometry><sphere radius="0.25"/></geometry>'
        '</collision></link>').replace('lower="-1.5" upper="1.5"', 'lower="-3" upper="3"')
    urdf = tmp_path / "sphere_below.urdf"
    urdf.write_text(text)
    args = ["tdgen", str(urdf), "--samples", "800", "--workers", "1", "--no-progress"]
    refused = CliRunner().invoke(main, [*args, "--out", str(tmp_path / "a")])
    assert refused.exit_code == 2, refused.output
    assert "l1 / mounting-surface" in refused.stderr and "--allow-collision l1/mounting-surface" in refused.stderr
    assert str(urdf) in refused.stderr and "twinmesh-urdf" not in refused.stderr and "--no-surface" not in refused.stderr
    allowed = CliRunner().invoke(main, [*args, "--out", str(tmp_path / "b"), "--allow-collision", "l1/mounting-surface"])
    assert allowed.exit_code == 0, allowed.output
    unknown = CliRunner().invoke(main, [*args, "--out", str(tmp_path / "c"), "--allow-collision", "l1/nothing-here"])
    assert unknown.exit_code == 2 and "'nothing-here'" in unknown.stderr and "mounting-surface" in unknown.stderr


def test_a_joint_with_a_comma_in_its_numbers_is_refused_by_name(tmp_path):
    """urdfdom reads `rpy="1.57, 0 0"` as an error too (KIT's ARMAR-6 URDF on the package index has two)."""
    text = arm_urdf(tmp_path).read_text().replace('<origin xyz="0 0 0.2"/>', '<origin xyz="0 0 0.2" rpy="1.57, 0 0"/>', 1)
    (tmp_path / "comma.urdf").write_text(text)
    with pytest.raises(RobotError, match=r"comma\.urdf: malformed <joint> 'j1' \(ValueError: <origin> rpy=\"1\.57, 0 0\" "
                                         r"is not three numbers separated by spaces\)"):
        Robot.load(tmp_path / "comma.urdf")


def test_a_zero_radius_sphere_leaves_the_arm_usable_and_the_fast_model_exact(tmp_path):
    """Some URDFs hold a link's place with `<sphere radius="0.00"/>` (KIT's ARMAR-4 on the package index: its
    ankles and eyes); its corners are one point, which has no hull (qhull failed, and tdgen with it): the
    fast model bounds it by the faces of its box instead."""
    from tdgen.robot.collision import CollisionWorld
    from tdgen.robot.fast_collision import COLLIDES, FREE, FastCollision
    from tdgen.robot.surroundings import default_scene
    from tdgen.sampling import random_configurations

    text = arm_urdf(tmp_path).read_text().replace(f'<link name="l2"><collision><geometry>{BOX}',
                                                  '<link name="l2"><collision><geometry><sphere radius="0.00"/>')
    (tmp_path / "placeholder.urdf").write_text(text)
    robot = Robot.load(tmp_path / "placeholder.urdf")
    world = CollisionWorld(robot, default_scene(reach=robot.reach()))
    try:
        fast = FastCollision(world)
        q = random_configurations(robot, 800, 4)
        verdict, exact = fast.spheres.verdicts(q), world.colliding(q)
        assert int(np.sum((verdict == FREE) & exact)) == 0
        assert int(np.sum((verdict == COLLIDES) & ~exact)) == 0
        assert np.mean(verdict == FREE) > 0.3, "the arm's free configurations need no exact test"
    finally:
        world.close()


def _with_frames(tmp_path: Path, frames: int, geometry: bool, name: str) -> Path:
    """The test arm with `frames` more links hanging by fixed joints from l2 (a humanoid's skin and sensor
    frames: bare, or each with a small box)."""
    shape = '<collision><geometry><box size="0.01 0.01 0.01"/></geometry></collision>' if geometry else ""
    more = "".join(f'<link name="skin_{i}">{shape}</link><joint name="skin_{i}_mount" type="fixed">'
                   f'<parent link="l2"/><child link="skin_{i}"/><origin xyz="0.03 0 {i * 0.001:.3f}"/></joint>'
                   for i in range(frames))
    path = tmp_path / name
    path.write_text(arm_urdf(tmp_path).read_text().replace("</robot>", more + "</robot>"))
    return path


def test_more_links_than_pybullet_holds_lose_their_bare_frames_or_are_refused_with_both_counts(tmp_path):
    """A pybullet body holds 128 links; beyond, every query of its state fails (IIT's iCub has 213, 150 of
    them frames without geometry: "GetBasePositionAndOrientation failed" and a traceback)."""
    from tdgen.robot.collision import CollisionWorld
    from tdgen.robot.surroundings import default_scene

    robot = Robot.load(_with_frames(tmp_path, 200, geometry=False, name="skin.urdf"))
    assert robot.load_path != robot.urdf_path
    world = CollisionWorld(robot, default_scene())
    try:
        q = np.zeros((4, len(robot.joints)))
        assert world.colliding(q).shape == (4,) and not world.colliding(q[:1])[0]
    finally:
        world.close()
    frames = Robot.load(_with_frames(tmp_path, 200, geometry=False, name="skin_tip.urdf"), ee="skin_3")
    assert frames.ee_link == "skin_3" and "skin_3" in frames.load_path.read_text()  # a chosen tip stays
    with pytest.raises(RobotError, match=r"solid\.urdf: 207 links, and pybullet holds at most 128 in one body "
                                         r"\(none is a frame without geometry that could be dropped\); cut"):
        Robot.load(_with_frames(tmp_path, 200, geometry=True, name="solid.urdf"))


TELESCOPE = """<?xml version="1.0"?>
<robot name="telescope">
  <link name="base"><collision><origin xyz="0 0 0.05"/><geometry><box size="0.3 0.3 0.1"/></geometry></collision></link>
  <link name="carriage"><collision><geometry><box size="0.12 0.12 0.12"/></geometry></collision></link>
  <link name="tube_1"><collision><origin xyz="0 0.175 0"/><geometry><box size="0.1 0.35 0.1"/></geometry></collision></link>
  <link name="tube_2"><collision><origin xyz="0 0.175 0"/><geometry><box size="0.08 0.35 0.08"/></geometry>
    </collision></link>
  <link name="tube_3"><collision><origin xyz="0 0.175 0"/><geometry><box size="0.06 0.35 0.06"/></geometry>
    </collision></link>
  <link name="wrist"><collision><origin xyz="0.05 0 0"/><geometry><box size="0.1 0.04 0.04"/></geometry></collision></link>
  <link name="tool0"/>
  <joint name="lift" type="prismatic"><parent link="base"/><child link="carriage"/><origin xyz="0 0 0.4"/>
    <axis xyz="0 0 1"/><limit lower="0" upper="0.8" effort="1" velocity="1"/></joint>
  <joint name="reach_1" type="prismatic"><parent link="carriage"/><child link="tube_1"/><origin xyz="0 0.06 0"/>
    <axis xyz="0 1 0"/><limit lower="0" upper="0.4" effort="1" velocity="1"/></joint>
  <joint name="reach_2" type="prismatic"><parent link="tube_1"/><child link="tube_2"/>
    <axis xyz="0 1 0"/><limit lower="0" upper="0.4" effort="1" velocity="1"/></joint>
  <joint name="reach_3" type="prismatic"><parent link="tube_2"/><child link="tube_3"/>
    <axis xyz="0 1 0"/><limit lower="0" upper="0.4" effort="1" velocity="1"/></joint>
  <joint name="yaw" type="revolute"><parent link="tube_3"/><child link="wrist"/><origin xyz="0 0.35 0"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="tool" type="fixed"><parent link="wrist"/><child link="tool0"/><origin xyz="0.1 0 0"/></joint>
</robot>
"""


def test_nested_telescoping_links_are_named_as_overlapping_by_design_and_allowing_them_frees_the_workspace(tmp_path):
    """A telescoping arm (a Stretch's kind): tubes nested in each other, which as collision boxes overlap
    whenever they are not drawn out past each other: the outer and the inner tube when drawn in (at
    rest), not half-way out (so not taken for touching by design: that needs both). tdgen names the
    pair, touching at rest and in a third of the poses, with the option that allows it; allowed, the
    samples it blocked are free. Arms that fold into themselves as often, not at rest, get no such
    line (the zoo's arms)."""
    from click.testing import CliRunner

    from devices.cli.main import main

    urdf = tmp_path / "telescope.urdf"
    urdf.write_text(TELESCOPE)
    args = ["tdgen", str(urdf), "--samples", "1500", "--workers", "1", "--no-progress"]
    plain = CliRunner().invoke(main, [*args, "--out", str(tmp_path / "a")])
    assert plain.exit_code == 0, plain.output
    lines = [line for line in plain.stderr.splitlines() if line.startswith("warning:")]
    assert len(lines) == 1 and "tube_1 / tube_3 (" in lines[0] and "touching at rest" in lines[0], plain.stderr
    assert lines[0].endswith("--allow-collision tube_1/tube_3"), lines[0]
    freed = CliRunner().invoke(main, [*args, "--out", str(tmp_path / "b"), "--allow-collision", "tube_1/tube_3"])
    assert freed.exit_code == 0 and "warning:" not in freed.stderr, freed.output
    from tdgen.robot.points_csv import read

    blocked = read(tmp_path / "a" / "points.csv")[1]
    allowed = read(tmp_path / "b" / "points.csv")[1]
    assert blocked.mean() > 0.35 and allowed.mean() < 0.15 and not (allowed & ~blocked).any(), (blocked.mean(),
                                                                                                  allowed.mean())

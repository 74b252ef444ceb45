"""The robot zoo: arms from robot-description packages nobody here picked (test extras), with the
chain each must get; the zoo's tests and the fast collision model's tests share it. Without the
packages the importing module is skipped (in CI it fails instead)."""
from __future__ import annotations

import importlib.metadata
import os
from pathlib import Path

import pytest


def _data(distribution: str, folder: str) -> Path | None:
    """A data package's folder, or None when it is not installed."""
    try:
        dist = importlib.metadata.distribution(distribution)
    except importlib.metadata.PackageNotFoundError:
        return None
    return Path(str(dist.locate_file(folder)))


def _icub() -> Path | None:
    """The iCub models' folder (a Gazebo model set: one folder per robot, `model.urdf` and `model.config`),
    installed under the environment's `share/iCub`, or None."""
    try:
        from icub_models import get_models_path
    except ImportError:
        return None
    return get_models_path()


SHARE = _data("example-robot-data", "cmeel.prefix/share/example-robot-data")
ARMAR = _data("armar", "armar/description/urdf")  # KIT's ARMAR humanoids: a second collection (CC BY-NC 4.0)
ICUB = _icub()  # IIT's iCub humanoids, a Gazebo model set (CC BY-SA 4.0)
STRETCH = _data("hello-robot-stretch-urdf", "stretch_urdf")  # Hello Robot's Stretch (Clear BSD)
if SHARE is None or ARMAR is None or ICUB is None or STRETCH is None:
    missing = ("example-robot-data" if SHARE is None else "armar" if ARMAR is None else "icub-models" if ICUB is None
               else "hello-robot-stretch-urdf")
    if os.environ.get("CI") == "true":
        pytest.fail(f"{missing} is not installed (a test extra: pip install -e '.[test]')", pytrace=False)
    pytest.skip(f"{missing} is not installed (pip install -e '.[test]')", allow_module_level=True)
ROBOTS = SHARE / "robots"

STRETCH_NESTED = [("link_arm_l4", "link_arm_l1"), ("link_lift", "link_arm_l2"), ("link_arm_l2", "link_arm_l0"),
                  ("link_lift", "link_arm_l1"), ("base_link", "link_arm_l3"), ("link_arm_l3", "link_arm_l0")]  # as named
# id: (URDF under robots/, Robot.load options, expected (base link, tip link, joints), what kind of arm)
ZOO = {
    "ur5": ("ur_description/urdf/ur5_robot.urdf", {}, ("world", "ee_link", 6), "6-DoF industrial"),
    "panda": ("panda_description/urdf/panda.urdf", {}, ("panda_link0", "panda_hand_tcp", 7),
              "7-DoF, fingers (one a mimic)"),
    "xarm7": ("xarm_description/urdf/xarm7.urdf", {}, ("world", "link_eef", 7), "7-DoF"),
    "kinova": ("kinova_description/robots/kinova.urdf", {}, ("base", "j2s6s200_end_effector", 6),
               "6-DoF, unlimited (continuous) joints"),
    "so100": ("so_arm_description/urdf/so100.urdf", {}, ("base", "gripper", 5), "5-DoF with a jaw"),
    "z1": ("z1_description/urdf/z1.urdf", {}, ("world", "gripperStator", 6), "6-DoF with a gripper joint"),
    "talos-arm": ("talos_data/robots/talos_left_arm.urdf", {}, ("arm_left_1_link", "gripper_left_base_link", 6),
                  "humanoid arm, gripper of mimic joints"),
    "baxter": ("baxter_description/urdf/baxter.urdf", {"ee": "left_wrist"}, ("base", "left_wrist", 7),
               "two arms: the left one picked"),
    "pr2": ("pr2_description/urdf/pr2.urdf", {"ee": "r_wrist_roll_link", "fixed": {"torso_lift_joint": 150.0}},
            ("base_footprint", "r_wrist_roll_link", 7), "two-arm mobile manipulator, torso held"),
    "tiago": ("tiago_description/robots/tiago.urdf", {"fixed": {"torso_lift_joint": 100.0}},
              ("base_footprint", "hand_palm_link", 7), "mobile manipulator with a five-finger hand, torso held"),
    "b1-z1": ("b1_description/urdf/b1-z1.urdf", {}, ("base", "gripperStator", 6), "an arm on a quadruped"),
    # from the armar package (an absolute path: ROBOTS / it is itself); zero-radius spheres hold some links' places
    "armar4-arm": (ARMAR / "armar4_fixed_hands_and_legs.urdf", {"base_link": "torso_pitch", "ee": "arm_wri2_r0"},
                   ("torso_pitch", "arm_wri2_r0", 8), "a humanoid's 8-DoF arm from its torso (KIT's ARMAR-4)"),
    # a Gazebo model set (icub-models): 213 links, 150 of them sensor and skin frames pybullet cannot hold;
    # its chest and upper arm meshes overlap at rest and in most poses, by design (tdgen names the pair)
    "icub-arm": (ICUB / "iCubGazeboV2_5/model.urdf",
                 {"base_link": "chest", "ee": "r_hand", "allowed_collisions": [("chest", "r_upper_arm")]},
                 ("chest", "r_hand", 7), "a humanoid's 7-DoF arm, 213 links (IIT's iCub, Gazebo models)"),
    # a lift and a telescoping arm: four nested tubes whose convex hulls overlap where the real ones nest (tdgen
    # names the two pairs that take most poses; the tip is the gripper's grasp centre, off the wrist's axis)
    "stretch": (STRETCH / "RE2V0/stretch_description_RE2V0_tool_stretch_gripper.urdf",
                {"allowed_collisions": STRETCH_NESTED}, ("base_link", "link_grasp_center", 6),
                "mobile manipulator: a lift and a telescoping arm, 5 prismatic joints (Hello Robot's Stretch 2)"),
}

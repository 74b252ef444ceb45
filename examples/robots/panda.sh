#!/bin/sh
# A foreign arm on a running lab: the Franka Panda of the example-robot-data package (a URDF nobody here
# wrote, meshes found beside it), standing on the workbench of ../scenes/workbench.json, as the Thing `panda`.
#
#   pip install example-robot-data             # once (it is among the test extras)
#   sh examples/robots/panda.sh                # until Ctrl-C; more `twinmesh robot` options may follow
#
# The lab is found with the global --connect option: LAB=tcp/HOST:7447 for a lab elsewhere (default
# tcp/127.0.0.1:7447). The tdgen service of the lab generates the Panda's TD, workspace hull and points
# (80,000 samples by default: SAMPLES=N for another count).
set -eu
LAB=${LAB:-tcp/127.0.0.1:7447}
SAMPLES=${SAMPLES:-80000}
HERE=$(dirname "$0")
URDF=$(python3 -c 'import importlib.metadata as m; print(m.distribution("example-robot-data").locate_file(
    "cmeel.prefix/share/example-robot-data/robots/panda_description/urdf/panda.urdf"))')
exec twinmesh --connect "$LAB" robot "$URDF" --name panda --scene "$HERE/../scenes/workbench.json" \
     --samples "$SAMPLES" "$@"

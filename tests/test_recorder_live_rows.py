"""The live view's stream sends each transform frame's newest pose per flush, and everything else as it is
logged: what a browser drawing a few frames a second can take in. A real RecordingStream writes to a
file that rerun-sdk's own reader reads back."""
import numpy as np
import pytest
import rerun as rr
from rerun_view import frame_transforms

from mesh.recorder.live_rows import NewestTransforms


@pytest.fixture
def stream(tmp_path):
    path = tmp_path / "live.rrd"
    rec = rr.RecordingStream("live-rows-test")
    rec.save(str(path))
    yield NewestTransforms(rec), path


def times(n: int) -> list[rr.TimeColumn]:
    return [rr.TimeColumn("time", timestamp=1000.0 + np.arange(n)), rr.TimeColumn("seq", sequence=np.arange(n))]


def close(live: NewestTransforms) -> None:
    live.flush()
    live.rec.disconnect()


def test_of_each_frame_only_its_newest_pose_goes_out_with_its_own_times(stream):
    live, path = stream
    frames = ["arm/link1", "cube", "arm/link1", "cube", "arm/link1"]
    columns = rr.Transform3D.columns(translation=np.arange(15.0).reshape(5, 3), quaternion=[[0.0, 0, 0, 1]] * 5,
                                     parent_frame=["tf#/world"] * 5, child_frame=frames)
    live.send_columns("robot/joints", times(5), columns)
    close(live)
    link, cube = frame_transforms(path, "/robot/joints", "arm/link1"), frame_transforms(path, "/robot/joints", "cube")
    assert [r["translation"] for r in link] == [[12.0, 13.0, 14.0]]
    assert [r["translation"] for r in cube] == [[9.0, 10.0, 11.0]]


def test_an_entity_placed_in_its_own_frame_keeps_its_newest_pose(stream):
    from recordings import read_column

    live, path = stream
    live.send_columns("belt", times(3), rr.Transform3D.columns(translation=[[0.0, 0, 0], [1, 0, 0], [2, 0, 0]]))
    close(live)
    assert read_column(path, "/belt", "Transform3D:translation") == [[[2.0, 0.0, 0.0]]]


def test_plots_and_everything_logged_keep_every_row(stream):
    from recordings import read_column

    live, path = stream
    live.send_columns("joints/arm", times(4), rr.Scalars.columns(scalars=np.array([[0.0], [1.0], [2.0], [3.0]])))
    live.set_time("time", timestamp=2000.0)
    for k, x in enumerate((1.0, 2.0)):
        live.set_time("seq", sequence=10 + k)
        live.log("cube", rr.Transform3D(translation=[x, 0, 0]))
    close(live)
    assert read_column(path, "/joints/arm", "Scalars:scalars") == [[0.0], [1.0], [2.0], [3.0]]
    assert len(read_column(path, "/cube", "Transform3D:translation")) == 2

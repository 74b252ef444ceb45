"""The live view's stream logs the current state again: what a late viewer gets from the server's
newest part of the stream is the whole state, not only what changed lately. A real RecordingStream
writes to a file that rerun-sdk's own reader reads back."""
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from mesh.recorder.live_state import LiveState

MAGENTA = 0xFF00FFFF  # a colour as Rerun packs it (RGBA)


BUDGET = 20_000  # bytes logged behind an entity before it is logged again


def busy(state: LiveState, n: int) -> None:
    """Log `n` rows of something else (a moving cube), as a busy lab does."""
    for i in range(n):
        state.log("cube", rr.Transform3D(translation=[i, 0, 0]))


@pytest.fixture
def stream(tmp_path):
    path = tmp_path / "live.rrd"
    rec = rr.RecordingStream("live-state-test")
    rec.save(str(path))
    state = LiveState(rec, budget=BUDGET)
    state.set_time("time", timestamp=1000.0)
    yield state, path


def rows(path: Path, entity: str, component: str) -> list[tuple[float, object]]:
    """(time, value) of each row of an entity's component, in time order."""
    from rerun.chunk import RrdReader

    table = RrdReader(path).stream().collect().reader("time", contents=entity).to_arrow_table().sort_by("time")
    times = [t.timestamp() for t in table.column("time").to_pylist()]
    values = table.column(f"{entity}:{component}").to_pylist()
    return [(t, v) for t, v in zip(times, values, strict=True) if v is not None]


def close(state: LiveState) -> None:
    state.flush()
    state.rec.disconnect()


def test_a_state_left_alone_is_logged_again_with_its_latest_value_once_enough_is_logged_behind_it(stream):
    state, path = stream
    state.log("lamp", rr.Boxes3D.from_fields(colors=[MAGENTA]))
    state.send_columns("belt", [rr.TimeColumn("time", timestamp=[1000.0, 1000.5])],
                       rr.Transform3D.columns(translation=np.array([[0.0, 0, 0], [1, 2, 3]])))
    assert state.log_current_state() == 0  # just logged: among the newest data
    busy(state, 30)
    assert state.log_current_state() == 2  # the lamp and the belt; the cube is logged all the time
    assert state.log_current_state() == 0  # just logged again
    close(state)
    lamp = rows(path, "/lamp", "Boxes3D:colors")
    assert [v for _, v in lamp] == [[MAGENTA], [MAGENTA]]
    assert lamp[1][0] > 1000.5  # at the present time, after everything logged before
    assert [v for _, v in rows(path, "/belt", "Transform3D:translation")][-1] == [[1.0, 2.0, 3.0]]


def test_a_quiet_lab_logs_nothing_again(stream):
    state, path = stream
    state.log("lamp", rr.Boxes3D.from_fields(colors=[MAGENTA]))
    for _ in range(100):
        assert state.log_current_state() == 0
    close(state)
    assert len(rows(path, "/lamp", "Boxes3D:colors")) == 1


def test_log_lines_are_not_repeated_and_a_cleared_entity_is_not_brought_back(stream):
    state, path = stream
    state.log("log", rr.TextLog("the lamp was switched on"))
    state.log("obstacles/crate", rr.Boxes3D(half_sizes=[[0.1, 0.1, 0.1]]))
    state.log("obstacles", rr.Clear(recursive=True))
    busy(state, 30)
    assert state.log_current_state() == 0
    close(state)
    assert len(rows(path, "/log", "TextLog:text")) == 1
    assert len(rows(path, "/obstacles/crate", "Boxes3D:half_sizes")) == 1


def test_static_data_is_left_to_the_server_which_keeps_it_anyway(stream):
    state, path = stream
    state.log("room", rr.Boxes3D(half_sizes=[[2.0, 2.0, 0.1]]), static=True)
    busy(state, 30)
    assert state.log_current_state() == 0
    close(state)


def test_each_frame_of_a_robots_joints_entity_is_logged_again_with_its_own_latest_transform(stream):
    """A robot's joints are one entity whose rows each name a frame: each frame's state is its own last row."""
    state, path = stream
    frames = ["arm/link1", "arm/link2", "arm/link1"]
    state.send_columns("arm/joints", [rr.TimeColumn("time", timestamp=[1000.0, 1000.0, 1000.5])],
                       rr.Transform3D.columns(translation=np.array([[1.0, 0, 0], [2, 0, 0], [3, 0, 0]]),
                                              parent_frame=["arm/base", "arm/link1", "arm/base"], child_frame=frames))
    busy(state, 30)
    assert state.log_current_state() == 2  # the two frames
    close(state)
    again = [(frame, translation) for t, frame, translation in frame_rows(path, "/arm/joints") if t > 1000.5]
    assert sorted(again) == [("arm/link1", [3.0, 0.0, 0.0]), ("arm/link2", [2.0, 0.0, 0.0])]


def frame_rows(path: Path, entity: str) -> list[tuple[float, str, list[float]]]:
    """(time, child frame, translation) of each transform row of an entity: rows at one time kept apart."""
    from rerun.chunk import RrdReader

    out = []
    for chunk in RrdReader(path).stream().filter(content=entity, is_static=False):
        batch = chunk.to_record_batch()
        if chunk.entity_path == entity and "Transform3D:child_frame" in batch.schema.names:
            out += [(t.timestamp(), f[0], v[0]) for t, f, v in zip(batch.column("time").to_pylist(),
                                                                    batch.column("Transform3D:child_frame").to_pylist(),
                                                                    batch.column("Transform3D:translation").to_pylist())]
    return out

"""A robot's joint samples as the recorder queues them: only what moved goes out, except after the robot was
drawn again at its zero pose, when the next sample places every joint (else a robot at rest would stand at
zero until a joint moves)."""
from mesh.recorder.joint_rows import JointRows


def test_a_sample_sends_only_the_joints_that_moved_and_none_when_nothing_moved():
    rows = JointRows()
    rows.add(0.0, 0, None, {"a": 1.0, "b": 2.0})
    rows.add(0.1, 1, None, {"a": 1.0, "b": 2.5})
    rows.add(0.2, 2, None, {"a": 1.0, "b": 2.5})  # at rest: nothing written
    values, moved = rows.take()
    assert moved.values == [{"a": 1.0, "b": 2.0}, {"b": 2.5}]
    assert values.values == [[1.0, 2.0], [1.0, 2.5]]


def test_after_a_redraw_the_next_sample_places_every_joint_even_at_rest():
    rows = JointRows()
    rows.add(0.0, 0, None, {"a": 1.0, "b": 2.0})
    rows.take()
    rows.redrawn()
    rows.add(0.1, 1, None, {})  # a sample without joints keeps the redraw pending
    rows.add(0.2, 2, None, {"a": 1.0, "b": 2.0})  # unchanged, yet written whole
    rows.add(0.3, 3, None, {"a": 1.0, "b": 2.0})  # and then only what moves again
    values, moved = rows.take()
    assert moved.values == [{"a": 1.0, "b": 2.0}]
    assert values.values == [[1.0, 2.0]]
    assert rows.names == ["a", "b"]

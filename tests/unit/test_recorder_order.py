"""The recorder's writer, without a mesh: a value the fetcher read never overwrites a newer one the
Thing published while the read was on its way (a lamp switched on just after a recorder joined
stays on in the recording)."""
from __future__ import annotations

import queue

import msgspec
import rerun as rr

from mesh.fabric.keys import Keys
from mesh.recorder.logger import _STOP, Message, _Writer
from tests.recordings import scalars

KEYS = Keys()
TD = {
    "@context": "https://www.w3.org/2022/wot/td/v1.1",
    "title": "lamp",
    "id": "urn:test:lamp",
    "securityDefinitions": {"nosec_sc": {"scheme": "nosec"}},
    "security": ["nosec_sc"],
    "properties": {"lightState": {"type": "integer", "minimum": 0, "maximum": 1, "forms": [{"href": "x"}]}},
}


def _record(tmp_path, messages: list[Message]) -> list[float]:
    path = tmp_path / "order.rrd"
    rec = rr.RecordingStream("order-test")
    rec.save(str(path))
    inbox: queue.Queue = queue.Queue()
    writer = _Writer(rec, KEYS, inbox)
    for m in [Message("sample", KEYS.td("lamp"), msgspec.json.encode(TD), 0.5), *messages, _STOP]:
        inbox.put(m)
    writer.start()
    writer.join(30)
    assert not writer.is_alive()
    return scalars(path, "/things/lamp/properties/lightState")


def test_a_read_asked_before_a_publication_does_not_overwrite_it(tmp_path):
    key = KEYS.property("lamp", "lightState")
    values = _record(tmp_path, [Message("sample", key, b"1", 2.0), Message("read", key, b"0", 1.0)])
    assert values == [1.0]


def test_a_read_asked_after_the_last_publication_is_recorded(tmp_path):
    key = KEYS.property("lamp", "lightState")
    values = _record(tmp_path, [Message("sample", key, b"1", 1.0), Message("read", key, b"0", 2.0)])
    assert values == [1.0, 0.0]

"""Reading Rerun recordings back in tests: the `rerun` command beside this Python, a process's ready
line, and an entity's values in recording order."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from waiting import eventually

RERUN = str(Path(sys.executable).with_name("rerun"))


def wait_for_line(log: Path, text: str, proc: subprocess.Popen, timeout: float = 30.0) -> str:
    """Wait until `text` appears in a process's log (the recorder's ready line)."""
    def logged() -> str | None:
        content = log.read_text() if log.exists() else ""
        if text in content:
            return content
        if proc.poll() is not None:
            raise RuntimeError(f"process exited ({proc.returncode}) before {text!r}:\n{content}")
        return None

    return eventually(logged, timeout=timeout, what=f"{text!r} logged in {log}")


def read_column(path: Path, entity: str, component: str) -> list:
    """The values an entity's component took, in recording order (the `seq` timeline)."""
    from rerun.chunk import RrdReader

    store = RrdReader(path).stream().collect()
    table = store.reader("seq", contents=entity).to_arrow_table().sort_by("seq")
    column = f"{entity}:{component}"
    if column not in table.column_names:
        return []
    return [v for v in table.column(column).to_pylist() if v is not None]


def scalars(path: Path, entity: str) -> list[float]:
    return [v[0] for v in read_column(path, entity, "Scalars:scalars")]


def field_scalars(path: Path, entity: str, field: str) -> list[float]:
    """The values one field of an object property took, where the object is plotted as one entity with a
    series per field (its series named `<field>` or `<field> (<unit>)`)."""
    names = latest_static(path, entity, "SeriesLines:names")
    at = [k for k, name in enumerate(names) if name.partition(" (")[0] == field]
    assert at, f"no series {field!r} at {entity}: {names}"
    return [row[at[0]] for row in read_column(path, entity, "Scalars:scalars")]


def texts(path: Path, entity: str) -> list[str]:
    return [line for v in read_column(path, entity, "TextLog:text") for line in v]


def latest_static(path: Path, entity: str, component: str):
    """The last static value of an entity's component."""
    from rerun.chunk import RrdReader

    rows = []
    for chunk in RrdReader(path).stream().filter(content=entity, is_static=True):
        batch = chunk.to_record_batch()
        if chunk.entity_path == entity and component in batch.schema.names:
            rows += zip(batch.column("rerun.controls.RowId").to_pylist(), batch.column(component).to_pylist())
    assert rows, f"nothing static at {entity} {component}"
    return sorted(rows, key=lambda r: r[0])[-1][1]


def placed(path: Path, entity: str, local):
    """Points of an entity's own frame in its parent's, by its static transform."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    t = np.array(latest_static(path, entity, "Transform3D:translation")[0])
    q = latest_static(path, entity, "Transform3D:quaternion")[0]
    return Rotation.from_quat(q).apply(np.asarray(local, dtype=float)) + t

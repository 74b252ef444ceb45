"""Rerun's view in tests: a recording's transform frames and joints, and the web viewer in headless Chromium.

`joint_values` and `frame_transforms` read a robot's joints back (one entity for its values, one series
per joint; one for its transforms, one frame per row). `frame_owners` reads a recording back through
rerun-sdk's own reader and says which entities log each named transform frame (Rerun refuses a frame
that two entities log statically, or two temporally: "Two entities define the same child frame").
`ViewerPage` opens Rerun's web viewer with `browser.chromium` (shared with the control page's tests)
and keeps what the page says on its console and which hosts it asks, so a test can find Rerun's
errors and any request that leaves the machine; `pixels` reads the page as an RGB array.
"""
from __future__ import annotations

import io
import re
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from urllib.parse import urlsplit

import numpy as np

VIEWPORT = {"width": 1280, "height": 800}
VIEW_AREA = (0.0, 0.1, 0.6, 0.9)  # the 3D view's part of the page: x0, y0, x1, y1 as fractions
_RERUN_LINE = re.compile(r"\b(ERROR|WARN)\s+(re_\w+|egui\w*|eframe)(::\w+)*:")
# Rerun's warnings about this machine, not about the data: a software rasteriser (no GPU here), the web
# backend lacking a window command, the welcome screen's examples that the page may not fetch (our policy)
ENVIRONMENT = ("Software rasterizer", "not implemented in web backend", "Failed to load examples")
LOCAL = {"127.0.0.1", "localhost", "::1", "[::1]"}


def frame_owners(path: Path) -> dict[tuple[str, bool], set[str]]:
    """(frame name, logged statically) -> the entities that log a transform to that frame."""
    from rerun.chunk import RrdReader

    owners: dict[tuple[str, bool], set[str]] = defaultdict(set)
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        if "Transform3D:child_frame" not in batch.schema.names:
            continue
        for frames in batch.column("Transform3D:child_frame").to_pylist():
            for frame in frames or []:
                owners[(frame, chunk.is_static)].add(chunk.entity_path)
    return dict(owners)


def joint_values(path: Path, entity: str, joint: str) -> list[float]:
    """One joint's values in recording order, from a robot's joints entity: one `Scalars` series per joint,
    named `<joint> (<unit>)` in row order by its `SeriesLines` (rows from before the joint joined left out)."""
    from recordings import read_column

    index = list(joint_units(path, entity)).index(joint)
    return [row[index] for row in read_column(path, entity, "Scalars:scalars") if len(row) > index]


def joint_units(path: Path, entity: str) -> dict[str, str]:
    """Joint -> the unit its series is named with, in the order of a row of the robot's joints entity."""
    from recordings import latest_static

    names = latest_static(path, entity, "SeriesLines:names")
    return dict(re.fullmatch(r"(.+) \((.+)\)", n).groups() for n in names)  # type: ignore[union-attr]


def frame_transforms(path: Path, entity: str, frame: str) -> list[dict]:
    """The transforms an entity logs over time for one child frame, in `seq` order: translation, quaternion
    and parent frame of each row (a robot's joints entity names a frame in each row)."""
    return transforms_by_frame(path, entity).get(frame, [])


def transforms_by_frame(path: Path, entity: str) -> dict[str, list[dict]]:
    """Child frame -> its transforms over time, as `frame_transforms` reads them. Read chunk by chunk: a
    dataframe query keeps one row per entity and time, where such an entity has one per frame."""
    from rerun.chunk import RrdReader

    rows: dict[str, list] = defaultdict(list)
    for chunk in RrdReader(path).stream().filter(content=entity, is_static=False):
        batch = chunk.to_record_batch()
        if chunk.entity_path != entity or "Transform3D:child_frame" not in batch.schema.names:
            continue
        columns = {c: batch.column(f"Transform3D:{c}").to_pylist()
                   for c in ("child_frame", "parent_frame", "translation", "quaternion")}
        for i, seq in enumerate(batch.column("seq").to_pylist()):
            row = {c: columns[c][i][0] for c in ("translation", "quaternion", "parent_frame")}
            rows[columns["child_frame"][i][0]].append((seq, row))
    return {frame: [r for _, r in sorted(found, key=lambda r: r[0])] for frame, found in rows.items()}


def shared_frames(path: Path) -> dict[tuple[str, bool], set[str]]:
    """The frames more than one entity logs (the same way, static or over time): Rerun's errors."""
    return {frame: entities for frame, entities in frame_owners(path).items() if len(entities) > 1}


class ViewerPage:
    """A Playwright page on Rerun's web viewer, with its console lines and requested hosts kept."""

    def __init__(self, page, url: str):
        self.page = page
        self.console: list[tuple[str, str]] = []
        self.hosts: set[str] = set()
        page.on("console", lambda m: self.console.append((m.type, m.text)))
        page.on("request", lambda r: self.hosts.add(urlsplit(r.url).hostname or r.url))
        page.goto(url, timeout=120_000)

    def rerun_problems(self) -> list[str]:
        """Rerun's own errors and warnings on the console, less those about this machine (ENVIRONMENT)."""
        lines = [text for kind, text in self.console if kind in ("error", "warning") and _RERUN_LINE.search(text)]
        return [line for line in lines if not any(e in line for e in ENVIRONMENT)]

    def foreign_hosts(self) -> set[str]:
        """Hosts other than this machine that the page asked for anything."""
        return {h for h in self.hosts if h not in LOCAL}

    def layout(self) -> tuple[int, str, int]:
        """How our page laid the viewer out: its scale, the WebGL renderer the browser reports, and the
        width in CSS pixels the viewer's frame has (the window's width / scale)."""
        return self.page.evaluate("""() => {
            const gl = document.createElement("canvas").getContext("webgl2");
            const info = gl && gl.getExtension("WEBGL_debug_renderer_info");
            const renderer = gl ? String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER)) : "";
            return [Number(document.documentElement.dataset.scale), renderer,
                    document.getElementById("viewer").clientWidth];
        }""")

    def save(self, path: Path) -> None:
        """The page as it is now, to a PNG (what a failing test leaves to look at)."""
        self.page.screenshot(path=str(path), timeout=180_000)

    def pixels(self) -> np.ndarray:
        """The page as it is drawn now, (height, width, 3) uint8."""
        return self._shot()

    def view_pixels(self) -> np.ndarray:
        """Only the 3D view (VIEW_AREA of the page): no plot or panel of the viewer's own colours in it,
        and a smaller picture, read sooner."""
        w, h = VIEWPORT["width"], VIEWPORT["height"]
        x0, y0, x1, y1 = VIEW_AREA
        return self._shot({"x": x0 * w, "y": y0 * h, "width": (x1 - x0) * w, "height": (y1 - y0) * h})

    def _shot(self, clip: dict | None = None) -> np.ndarray:
        from PIL import Image

        png = self.page.screenshot(timeout=180_000, clip=clip)
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


@contextmanager
def viewer_page(url: str) -> Iterator[ViewerPage]:
    """Rerun's web viewer at `url` in a headless Chromium (skipped where no Chromium can be had)."""
    from browser import chromium

    with chromium() as browser:
        page = browser.new_page(viewport=VIEWPORT)  # type: ignore[attr-defined]
        try:
            yield ViewerPage(page, url)
        finally:
            page.close()


def in_software(renderer: str) -> bool:
    """Whether a WebGL renderer's name (`ViewerPage.layout`) is one our page counts as software."""
    from mesh.recorder.web_viewer import SOFTWARE_RENDERERS

    return any(s in renderer.lower() for s in SOFTWARE_RENDERERS)


def room_drawn(pixels: np.ndarray) -> bool:
    """The 3D view (the left three fifths of the page) shows a scene: light walls and darker floor and
    tables in many shades, not an empty panel nor the dark loading screen."""
    h, w, _ = pixels.shape
    x0, y0, x1, y1 = VIEW_AREA
    area = pixels[round(y0 * h): round(y1 * h), round(x0 * w): round(x1 * w)]
    brightest = area.max(axis=2)
    shades = len(np.unique(area.reshape(-1, 3) // 16, axis=0))
    return float((brightest < 200).mean()) > 0.2 and float((brightest > 200).mean()) > 0.2 and shades > 100


def colour_share(pixels: np.ndarray, rgb: tuple[int, int, int], tolerance: float = 0.12) -> float:
    """The share of pixels whose hue and saturation are those of `rgb` (any brightness: the view shades
    its faces), e.g. a magenta lamp under the view's light."""
    px = pixels.astype(float) / 255.0
    target = np.asarray(rgb, dtype=float) / 255.0
    brightness = px.max(axis=2, keepdims=True)
    lit = brightness[..., 0] > 0.2
    normalised = px / np.maximum(brightness, 1e-6)
    close = np.abs(normalised - target / target.max()).max(axis=2) < tolerance
    return float((close & lit).mean())

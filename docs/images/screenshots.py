"""Takes the pictures of the README and the docs (docs/images/*.png) from a running lab.

    twinmesh up --speed max &          # a lab on the default ports
    twinmesh wait
    python docs/images/screenshots.py  [HTTP_URL] [VIEW_URL]

Headless Chromium through Playwright (the test extras), software WebGL for the 3D view. The page is taken once
the live values are in and the 3D view once two pictures 5 s apart agree.
"""
from __future__ import annotations

import base64
import io
import shutil
import sys
import time
from pathlib import Path

from playwright.sync_api import sync_playwright

HERE = Path(__file__).parent
ARGS = ["--no-sandbox", "--headless", "--disable-gpu", "--disable-background-networking", "--no-first-run",
        "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]


def main(http: str = "http://127.0.0.1:8080/", view: str = "http://127.0.0.1:9090/?scale=1") -> None:
    """`scale=1`: every pixel drawn, as a browser with a GPU shows the view (this one renders in software)."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=ARGS)
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.goto(http)
        page.wait_for_load_state("load")  # not "networkidle": the live values stream over SSE
        page.wait_for_timeout(5000)  # the live values arrive over SSE after the page has loaded
        page.screenshot(path=str(HERE / "control-page.png"))
        view_page = browser.new_page(viewport={"width": 1280, "height": 800})
        view_page.set_default_timeout(180_000)  # software WebGL on a busy machine draws slowly
        view_page.goto(view)
        cdp = view_page.context.new_cdp_session(view_page)  # Playwright's own waits for fonts the viewer never settles
        last, deadline = b"", time.monotonic() + 300
        while time.monotonic() < deadline:
            view_page.wait_for_timeout(5000)
            now = base64.b64decode(cdp.send("Page.captureScreenshot", {"format": "png"})["data"])
            if now == last and coloured(now) > 2000:  # the lab drawn, and the viewer caught up with the stream
                break
            last = now
        (HERE / "view-3d.png").write_bytes(last)
        browser.close()


def coloured(png: bytes) -> int:
    """Coloured pixels in the 3D pane (the left half, below its tabs): an empty grid is grey, the lab is not."""
    from PIL import Image

    image = Image.open(io.BytesIO(png)).convert("HSV")
    pane = image.crop((0, 70, image.width * 3 // 5, image.height))
    hsv = pane.tobytes()
    return sum(1 for i in range(0, len(hsv), 3) if hsv[i + 1] > 80 and hsv[i + 2] > 60)


if __name__ == "__main__":
    main(*sys.argv[1:])

"""The view's page of our own (`mesh.recorder.web_viewer`): Rerun's viewer in a frame, enlarged where WebGL
renders in software (within `SOFTWARE_PIXELS` whatever the window), and a pointer that still lands where the
viewer drew what it points at.

A `ViewerServer` with no stream behind it is enough: what is tested is how our page lays out Rerun's page and
carries input into it, in a real headless Chromium (software WebGL here).
"""
import pytest
from rerun_view import VIEWPORT, ViewerPage, in_software

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def server():
    from labs import free_port

    from mesh.recorder.web_viewer import ViewerServer, viewer_url

    port = free_port()
    viewer = ViewerServer(("127.0.0.1", port), free_port())
    yield viewer_url("127.0.0.1", port, 9)  # a stream nobody serves: the page's layout is what counts
    viewer.close()


@pytest.fixture(scope="module")
def browser():
    from browser import chromium

    with chromium() as b:
        yield b


def opened(browser, url: str):
    page = browser.new_page(viewport=VIEWPORT)
    page.goto(url, timeout=120_000)
    page.wait_for_function("() => document.getElementById('viewer').contentDocument?.readyState === 'complete'",
                           timeout=120_000)
    return page, next(f for f in page.frames if "/viewer.html" in f.url)


@pytest.mark.parametrize("scale", [2, 3])
def test_a_click_on_the_enlarged_page_lands_where_the_viewer_drew_it(server, browser, scale):
    page, frame = opened(browser, f"{server}&scale={scale}")
    try:
        width, height = frame.evaluate("() => [innerWidth, innerHeight]")  # CSS pixels, rounded
        assert abs(width - VIEWPORT["width"] / scale) < 1 and abs(height - VIEWPORT["height"] / scale) < 1
        frame.evaluate("""() => { window.__clicks = [];
            addEventListener('pointerdown', e => window.__clicks.push([e.clientX, e.clientY]), true); }""")
        page.mouse.click(600, 300)
        page.mouse.click(1200, 750)
        assert frame.evaluate("() => window.__clicks") == [[600 / scale, 300 / scale], [1200 / scale, 750 / scale]]
        assert "url=rerun%2Bhttp" in frame.url and "scale=" not in frame.url  # the stream's address, passed on
    finally:
        page.close()


def test_scale_1_gives_the_viewer_every_pixel_and_auto_follows_the_renderer(server, browser):
    page, frame = opened(browser, f"{server}&scale=1")
    try:
        assert frame.evaluate("() => [innerWidth, innerHeight]") == [VIEWPORT["width"], VIEWPORT["height"]]
    finally:
        page.close()

    page = browser.new_page(viewport=VIEWPORT)
    try:
        scale, renderer, width = ViewerPage(page, server).layout()
        assert scale == (2 if in_software(renderer) else 1), renderer
        assert width == VIEWPORT["width"] // scale
    finally:
        page.close()


def test_auto_keeps_a_software_renderer_within_its_pixels_in_any_window(server, browser):
    from mesh.recorder.web_viewer import SOFTWARE_PIXELS

    for width, height in ((1920, 1080), (800, 500)):
        page = browser.new_page(viewport={"width": width, "height": height})
        try:
            scale, renderer, _ = ViewerPage(page, server).layout()
            if not in_software(renderer):
                pytest.skip(f"this browser renders WebGL on a GPU ({renderer}): auto draws every pixel there")
            inner = page.evaluate("() => [document.getElementById('viewer').clientWidth, "
                                  "document.getElementById('viewer').clientHeight]")
            assert inner[0] * inner[1] <= SOFTWARE_PIXELS * 1.01  # rounding to whole CSS pixels
            assert scale == pytest.approx(max(1.0, (width * height / SOFTWARE_PIXELS) ** 0.5), abs=0.01)
        finally:
            page.close()

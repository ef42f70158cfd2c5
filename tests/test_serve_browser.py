"""The web app in a real browser: headless Chromium (Debian's ``chromium`` and
``chromium-driver``, installed by .ci/run) driven through selenium opens the page, generates, and
the test checks the drawing, a download and an error message.

The test watches the page as a user's tools would: the elements it shows (the frame slider, the
clock, captions, messages) and the User Timing marks every request leaves ("t2m:request",
"t2m:answer", "t2m:first-frame"; app.js); the page has no hooks for tests.

Outside CI the test is skipped, saying why, when Chromium or its driver is not installed; in CI
(``CI=true``) their absence is a failure.
"""

from __future__ import annotations

import io
import os
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from t2m.pipeline import TextToMotion
from t2m.serve.server import make_server

LEFT, RIGHT = (0x1F, 0x6F, 0xD1), (0xD6, 0x40, 0x2B)  # the renderings' limb colours
HIGHLIGHT = (0x2C, 0xA0, 0x2C)  # an edit's kept joints


def _browser_paths() -> tuple[str, str]:
    browser = next(filter(None, map(shutil.which, ["chromium", "chromium-browser"])), None)
    driver = shutil.which("chromedriver")
    missing = [name for name, path in (("chromium", browser), ("chromedriver", driver)) if not path]
    if missing:
        reason = (
            f"{' and '.join(missing)} not installed (Debian: apt-get install chromium "
            "chromium-driver; .ci/run installs them)"
        )
        if os.environ.get("CI") == "true":
            pytest.fail(f"the browser test must run in CI: {reason}")
        pytest.skip(reason)
    return browser, driver


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    binary, driver_path = _browser_paths()
    webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is in the test extra")
    from selenium.webdriver.chrome.service import Service

    downloads = tmp_path_factory.mktemp("downloads")
    options = webdriver.ChromeOptions()
    options.binary_location = binary
    for argument in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu"):
        options.add_argument(argument)
    options.add_argument("--window-size=1400,1000")
    options.add_experimental_option(
        "prefs",
        {"download.default_directory": str(downloads), "download.prompt_for_download": False},
    )
    driver = webdriver.Chrome(options=options, service=Service(driver_path))
    driver.downloads = downloads
    yield driver
    driver.quit()


@pytest.fixture(scope="module")
def page(browser, tiny_run, tmp_path_factory):
    pipe = TextToMotion.from_checkpoints(tiny_run, device="cpu")
    server = make_server(pipe, str(tiny_run), port=0, work_dir=tmp_path_factory.mktemp("work"))
    server.start_in_thread()
    browser.get(server.url)
    _wait(browser, "return document.body.dataset.ready === 'true'")
    yield browser
    server.shutdown_app()


def _wait(driver, script: str, timeout: float = 30.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = driver.execute_script(script)
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for: {script}")


def _canvas_pixels(driver) -> np.ndarray:
    from PIL import Image

    png = driver.find_element("id", "view").screenshot_as_png
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)


def _colour_count(pixels: np.ndarray, colour: tuple[int, int, int], tolerance: int = 40) -> int:
    return int((np.abs(pixels - np.array(colour)).sum(axis=-1) < tolerance).sum())


# The last request's timing marks (ms): click, answer, first drawn frame; null until drawn.
TIMING = """const mark = (name) => performance.getEntriesByName(name, 'mark').at(-1);
const [clicked, answered, firstFrame] = ['t2m:request', 't2m:answer', 't2m:first-frame'].map(mark);
return firstFrame && {clicked: clicked.startTime, answered: answered.startTime,
                      firstFrame: firstFrame.startTime};"""
SLIDER = "Number(document.getElementById('scrub').value)"  # the frame drawn last


def _generate(driver, prompts: str, samples: int = 3) -> None:
    box = driver.find_element("id", "prompts")
    box.clear()
    box.send_keys(prompts)
    count = driver.find_element("id", "samples")
    count.clear()
    count.send_keys(str(samples))
    driver.execute_script("performance.clearMarks()")
    driver.find_element("id", "generate").click()


def _wait_for_frames(driver, frame: int, steps: int) -> None:
    """Until the view has drawn ``steps`` frames past ``frame`` (or looped round to before it)."""
    _wait(driver, f"return {SLIDER} < {frame} || {SLIDER} >= {frame + steps}")


def test_page_generates_and_draws_the_figures(page):
    _generate(page, "a person walks forward")
    timing = _wait(page, TIMING)
    assert timing["firstFrame"] >= timing["answered"] >= timing["clicked"]
    assert not page.find_element("id", "error").is_displayed()
    captions = page.find_element("id", "captions").text
    assert captions.count("a person walks forward") == 3
    first = _canvas_pixels(page)
    assert first.std() > 5  # not blank
    assert _colour_count(first, LEFT) > 200 and _colour_count(first, RIGHT) > 200
    _wait_for_frames(page, page.execute_script(f"return {SLIDER}"), steps=5)
    later = _canvas_pixels(page)
    assert np.abs(later - first).sum(axis=-1).astype(bool).mean() > 0.001  # the figures moved
    # pause: the picture stands still; scrub: it shows the chosen frame
    page.find_element("id", "play").click()
    _wait(page, "return document.getElementById('play').textContent === 'Play'")
    time.sleep(0.3)
    still = _canvas_pixels(page)
    assert np.array_equal(still, _canvas_pixels(page))
    page.execute_script(
        "const s = document.getElementById('scrub'); s.value = 0;"
        "s.dispatchEvent(new Event('input'));"
    )
    _wait(page, "return document.getElementById('clock').textContent === '0.00 s'")
    assert page.find_element("id", "clock").text == "0.00 s"
    # one at a time: the layout menu lists the three motions and shows one
    options = page.find_elements("css selector", "#layout option")
    assert len(options) == 4
    all_three = _colour_count(_canvas_pixels(page), LEFT)
    options[1].click()
    time.sleep(0.2)
    assert _colour_count(_canvas_pixels(page), LEFT) < 0.8 * all_three
    options[0].click()
    page.find_element("id", "play").click()
    history = page.find_elements("css selector", "#history li button")
    assert len(history) >= 1 and "a person walks forward" in history[0].text


def test_page_bvh_download_reads_back(page):
    from dataset_tools.sources.bvh import BvhOptions, load_bvh_motion

    if not page.find_elements("css selector", "#downloads a[data-kind='bvh']"):
        _generate(page, "a person walks forward")
        _wait(page, "return document.querySelector(\"#downloads a[data-kind='bvh']\")")
    link = page.find_element("css selector", "#downloads a[data-kind='bvh']")
    link.click()
    target = Path(page.downloads) / "sample00_rep00.bvh"
    deadline = time.monotonic() + 30
    while not target.exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert target.exists(), f"no download in {list(Path(page.downloads).iterdir())}"
    motion = load_bvh_motion(target, BvhOptions())
    assert motion.joints.shape[1:] == (22, 3) and motion.fps == pytest.approx(20.0)
    assert np.isfinite(motion.joints).all()


@pytest.mark.parametrize(
    ("prompts", "words"),
    [("", "empty prompt"), ("qwzx blorf", "no known word"), ("a person walks#5", "out of range")],
)
def test_page_shows_errors_in_words(page, prompts, words):
    _generate(page, prompts, samples=1)
    text = _wait(
        page,
        "const e = document.getElementById('error'); return !e.hidden && e.textContent",
    )
    assert words in text
    assert page.find_element("id", "generate").is_enabled()


def test_page_edits_a_motion_in_the_view(page):
    from selenium.webdriver.support.ui import Select

    _generate(page, "a person walks forward#80", samples=1)
    _wait(page, TIMING)
    Select(page.find_element("id", "edit-source-kind")).select_by_value("current")
    Select(page.find_element("id", "edit-mode")).select_by_value("continue")
    page.find_element("id", "edit-text").send_keys("a person jumps up and down")
    page.execute_script("performance.clearMarks()")
    page.find_element("id", "edit-run").click()
    _wait(page, TIMING)
    assert not page.find_element("id", "error").is_displayed()
    page.find_element("id", "play").click()  # pause on the first frames: the kept start
    page.execute_script(
        "const s = document.getElementById('scrub'); s.value = 5; s.dispatchEvent(new Event('input'));"
    )
    time.sleep(0.2)
    kept = _colour_count(_canvas_pixels(page), HIGHLIGHT)
    assert kept > 200  # the kept start is drawn in the highlight colour
    history = page.find_elements("css selector", "#history li button")
    assert history[0].text.split(": ", 1)[1].startswith("continue: a person jumps up and down")
    page.find_element("id", "play").click()


def test_page_names_words_the_model_does_not_know(page):
    _generate(page, "a person walks forward blorf#40", samples=1)
    text = _wait(
        page, "const w = document.getElementById('warnings'); return !w.hidden && w.textContent"
    )
    assert "not trained on blorf" in text
    assert not page.find_element("id", "error").is_displayed()


BACKGROUND, GRID = (0xFB, 0xFB, 0xFA), (0xD2, 0xD2, 0xD2)  # the view's (viewer.js)
# Frames the page draws per second over `seconds` (requestAnimationFrame callbacks: the viewer
# draws in its own, so a slow drawing lowers the rate), and the mean milliseconds the page's
# callbacks take per frame (the viewer asks for each next frame through the global
# requestAnimationFrame, wrapped here while measuring).
FRAME_RATE = """const [seconds, done] = arguments;
const original = window.requestAnimationFrame;
let busy = 0;
window.requestAnimationFrame = (callback) => original((now) => {
  const begin = performance.now(); callback(now); busy += performance.now() - begin;
});
let frames = 0, start = null;
function tick(now) {
  if (start === null) { start = now; busy = 0; } else frames++;
  if (now - start < seconds * 1000) original(tick);
  else {
    window.requestAnimationFrame = original;
    done({fps: frames / ((now - start) / 1000), ms: busy / frames});
  }
}
original(tick);"""


def _figure(driver, value: str) -> None:
    from selenium.webdriver.support.ui import Select

    Select(driver.find_element("id", "figure")).select_by_value(value)
    time.sleep(0.2)


@pytest.mark.timed
def test_page_draws_a_body_and_keeps_its_frame_rate(page):
    """The "draw" menu: body (capsules, the default) covers far more of the view than sticks, in
    the same colours; the choice is remembered. Then 8 motions play side by side and the page's
    frame rate is measured in both modes (T2M_FPS_SECONDS seconds each, default 1.5). Timed: it
    runs apart from the parallel pass, so that no other test's work sets its frame rate."""
    assert page.find_element("id", "figure").get_attribute("value") == "body"
    _generate(page, "a person walks forward#40", samples=2)
    _wait(page, TIMING)
    page.find_element("id", "play").click()  # pause: both modes draw the same frame
    _wait(page, "return document.getElementById('play').textContent === 'Play'")
    ink = {}
    for mode in ("sticks", "body"):
        _figure(page, mode)
        pixels = _canvas_pixels(page)
        assert page.execute_script("return localStorage.getItem('t2m-figure')") == mode
        far = [np.abs(pixels - np.array(c)).sum(axis=-1) > 60 for c in (BACKGROUND, GRID)]
        ink[mode] = int((far[0] & far[1]).sum())  # the figures' pixels
        assert _colour_count(pixels, LEFT) > 200 and _colour_count(pixels, RIGHT) > 200
    assert ink["body"] > 1.8 * ink["sticks"], ink
    page.find_element("id", "play").click()

    _generate(page, "a person walks forward#80", samples=8)
    _wait(page, TIMING)
    seconds = float(os.environ.get("T2M_FPS_SECONDS", "1.5"))
    rates = {}
    for mode in ("sticks", "body"):
        _figure(page, mode)
        rates[mode] = page.execute_async_script(FRAME_RATE, seconds)
    print(f"8 motions, {seconds:g} s each: frames per second and ms per drawing {rates}")
    assert rates["body"]["fps"] > 5, rates  # it still plays as a motion, not a slide show
    # Both modes drew every frame they were given. Which one costs more per drawing is not
    # asserted: at under 2 ms each the two differ by less than a busy neighbour process moves
    # either (CI: body 1.71 ms, sticks 1.77 ms with the other test worker running).
    assert rates["body"]["ms"] > 0 and rates["sticks"]["ms"] > 0, rates

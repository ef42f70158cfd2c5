"""The web page's edit panel composes from a source, in a real browser (headless Chromium through
selenium, as tests/test_serve_browser.py; skipped outside CI when they are not installed):
compose starts from no source, a motion in the view can be chosen, its last seconds are kept
and drawn on the timeline strip, and the request comes back as one motion of the right length.
"""

from __future__ import annotations

from test_serve_browser import TIMING, _generate, _wait, browser, page  # noqa: F401 (fixtures)


def test_panel_composes_after_a_motion_in_the_view(page):  # noqa: F811 (the fixture)
    from selenium.webdriver.support.ui import Select

    _generate(page, "a person walks forward#60", samples=1)
    _wait(page, TIMING)
    mode, kind = (
        Select(page.find_element("id", "edit-mode")),
        page.find_element("id", "edit-source-kind"),
    )
    mode.select_by_value("compose")
    assert kind.get_attribute("value") == "none"  # compose makes a new motion unless told
    Select(kind).select_by_value("current")
    last = page.find_element("id", "edit-keep-last")
    last.clear()
    last.send_keys("1")
    timeline = page.find_element("id", "edit-timeline-text")
    timeline.clear()
    timeline.send_keys("a person jumps up and down#2")
    note = page.find_element("id", "edit-timeline-note").text
    assert note.startswith("3.0 s"), note  # 1 s kept + 2 s made
    page.execute_script("performance.clearMarks()")
    page.find_element("id", "edit-run").click()
    _wait(page, TIMING)
    assert not page.find_element("id", "error").is_displayed()
    history = page.find_elements("css selector", "#history li button")
    assert history[0].text.split(": ", 1)[1].startswith("compose: a person jumps up and down")
    assert page.execute_script("return Number(document.getElementById('scrub').max)") == 59
    # "none" is compose's only: another mode goes back to an upload
    Select(kind).select_by_value("none")
    mode.select_by_value("continue")
    assert kind.get_attribute("value") == "upload"

"""The tiny study's report.html in a real browser: headless Chromium from the distribution
(installed by ``scripts/setup.sh --test``, ``make test``), driven by Selenium.

Checks what a reader sees: the page renders without a console error, the answer (the
headline table with intervals and the findings) comes before the first pipeline section,
no table is wider than the page, and every embedded figure decodes.
"""

from __future__ import annotations

import shutil

import pytest

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver")



@pytest.fixture(scope="module")
def browser():
    # a failure, not a skip: the suite's set-up installs the browser, and a report check
    # that silently does not run is worse than a red test naming the fix
    if CHROMIUM is None or DRIVER is None:
        pytest.fail("headless Chromium and chromedriver are missing: `make test` installs them "
                    "(scripts/setup.sh --test: apt-get install chromium chromium-driver)")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--window-size=1280,1000"):
        opts.add_argument(arg)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(executable_path=DRIVER), options=opts)
    try:
        yield driver
    finally:
        driver.quit()


def test_report_renders_without_errors_and_answers_first(tiny_study, browser):
    page = tiny_study.run / "report.html"
    browser.get(page.as_uri())
    errors = [e for e in browser.get_log("browser") if e.get("level") == "SEVERE"]
    assert errors == [], errors
    # the answer first: the summary's headline table and findings precede every section
    order = browser.execute_script(
        "return Array.from(document.querySelectorAll('h2,h3')).map(h => h.textContent);")
    assert order[0] == "Summary", order
    first_section = order.index("Scene and tour")
    assert order.index("Held-out scores with 95 % intervals") < first_section
    assert order.index("Findings") < first_section
    # no table runs off the page: each fits the body's content width
    overflow = browser.execute_script("""
        const body = document.body.getBoundingClientRect();
        return Array.from(document.querySelectorAll('table')).filter(
            t => t.getBoundingClientRect().right > body.right + 1
                 || t.scrollWidth > t.parentElement.clientWidth + 1).map(
            t => t.previousElementSibling ? t.parentElement.previousElementSibling.textContent
                                          : t.outerHTML.slice(0, 80));""")
    assert overflow == [], overflow
    # every embedded figure decodes (a broken data URL has naturalWidth 0)
    broken = browser.execute_script(
        "return Array.from(document.images).filter(i => !i.complete || i.naturalWidth === 0)"
        ".map(i => i.alt);")
    assert broken == [], broken
    n_images = browser.execute_script("return document.images.length;")
    assert n_images >= 5
    # missing values read '–', never Python's None
    assert "None" not in browser.execute_script(
        "return Array.from(document.querySelectorAll('td')).map(t => t.textContent).join('|');")


def test_the_overflow_check_sees_a_table_wider_than_the_page(tmp_path, browser):
    # the check above can fail: a 60-column table of long numbers overflows
    cells = "".join(f"<td>{10**12 + k}</td>" for k in range(60))
    html = (f"<html><body style='max-width:600px'><h3>t</h3><div class='tw'><table><tr>{cells}"
            "</tr></table></div></body></html>")
    (tmp_path / "wide.html").write_text(html)
    browser.get((tmp_path / "wide.html").as_uri())
    wide = browser.execute_script(
        "const b = document.body.getBoundingClientRect();"
        "return Array.from(document.querySelectorAll('table')).filter("
        "t => t.getBoundingClientRect().right > b.right + 1).length;")
    assert wide == 1

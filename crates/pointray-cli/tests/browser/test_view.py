"""`pointray view` in a real browser: headless Chromium (Debian's chromium and chromium-driver,
driven by Selenium) loads the page, the model appears, and a drag turns it. The model is
$POINTRAY_VIEW_MODEL (`.ci/run` gives the Stanford bunny where ../shared/data is), else the demo.

    apt-get install -y chromium chromium-driver && pip install selenium pytest
    POINTRAY_BIN=target/release/pointray pytest crates/pointray-cli/tests/browser
"""

import base64
import os
import shlex
import subprocess
import time

import pytest
from selenium import webdriver
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By

BIN = os.environ.get("POINTRAY_BIN")
MODEL = os.environ.get("POINTRAY_VIEW_MODEL")

# How many channel values of the PNG `arguments[0]` (base64) differ from the canvas's by more
# than one level, the most any does, and how many there are.
COMPARE = """
const [png, done] = arguments;
const image = new Image();
image.onload = () => {
  const other = new OffscreenCanvas(image.width, image.height).getContext("2d");
  other.drawImage(image, 0, 0);
  const a = other.getImageData(0, 0, image.width, image.height).data;
  const c = document.getElementById("view");
  const b = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
  let differ = 0, most = 0;
  for (let i = 0; i < a.length; i++) {
    const d = Math.abs(a[i] - b[i]);
    most = Math.max(most, d);
    if (d > 1) differ++;
  }
  done([differ, most, a.length, b.length]);
};
image.src = "data:image/png;base64," + png;
"""

# A digest of the canvas and how many of its pixels are brighter than the dark background.
SNAPSHOT = """
const c = document.getElementById("view");
const d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
let digest = 0, lit = 0;
for (let i = 0; i < d.length; i += 4) {
  digest = (Math.imul(digest, 31) + d[i] + 7 * d[i + 1] + 13 * d[i + 2]) >>> 0;
  if (d[i] + d[i + 1] + d[i + 2] > 150) lit++;
}
return [digest, lit, window.pointrayFrames()];
"""


@pytest.fixture
def viewer():
    server = subprocess.Popen(
        [BIN, "-q", "view", *([MODEL] if MODEL else []), "--port", "0", "--no-open", "--width", "200", "--height", "150",
         "--spp", "4"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        yield server.stdout.readline().split()[-1]
    finally:
        server.terminate()
        server.wait()


@pytest.fixture
def browser():
    options = webdriver.ChromeOptions()
    for flag in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=400,400"):
        options.add_argument(flag)
    driver = webdriver.Chrome(options=options, service=webdriver.ChromeService("/usr/bin/chromedriver"))
    try:
        yield driver
    finally:
        driver.quit()


def wait_for(condition, seconds=30):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        value = condition()
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"not within {seconds} s")


@pytest.mark.skipif(not BIN, reason="POINTRAY_BIN not set")
def test_the_model_appears_and_a_drag_turns_it(viewer, browser, tmp_path):
    start = time.monotonic()
    browser.get(viewer)
    # The model appears: frames drawn, and pixels brighter than the background.
    wait_for(lambda: (s := browser.execute_script(SNAPSHOT))[2] > 0 and s[1] > 500 and s)
    print(f"{MODEL or 'the demo'} visible {time.monotonic() - start:.2f} s after the page was asked for")
    # The view at rest refines (four samples a pixel), then a drag turns it.
    time.sleep(1.0)
    rested = browser.execute_script(SNAPSHOT)
    canvas = browser.find_element(By.ID, "view")
    ActionChains(browser).move_to_element(canvas).click_and_hold().move_by_offset(60, 10).release().perform()
    turned = wait_for(lambda: (s := browser.execute_script(SNAPSHOT))[2] > rested[2] and s[0] != rested[0] and s)
    assert turned[1] > 500, "the model is still in view"
    assert "error" not in browser.find_element(By.ID, "error").text
    # "Copy CLI command": the command line draws the view the page converged to.
    converged = lambda: (m := browser.execute_script("return window.pointrayMeta()")) and m["samples"] == 4
    wait_for(converged)
    command = browser.execute_script("return window.pointrayCommand()")
    differ, most, values = matches_the_command_line(browser, command, tmp_path)
    print(f"the command line's image against the page's: {differ} of {values} values differ by more than 1 (most {most})")


@pytest.mark.skipif(not BIN, reason="POINTRAY_BIN not set")
def test_the_prefilter_box_draws_what_the_command_line_draws(viewer, browser, tmp_path):
    browser.get(viewer)
    wait_for(lambda: (s := browser.execute_script(SNAPSHOT))[2] > 0 and s[1] > 500 and s)
    # Ticked, the prefilter takes the view down to one ray a pixel.
    browser.find_element(By.ID, "prefilter").click()
    done = lambda: (m := browser.execute_script("return window.pointrayMeta()")) and m["prefilter"] and \
        m["samples"] == 1 and m["scale"] == 1
    wait_for(done)
    assert "error" not in browser.find_element(By.ID, "error").text
    command = browser.execute_script("return window.pointrayCommand()")
    assert "--prefilter" in command and "--spp 1" in command, command
    matches_the_command_line(browser, command, tmp_path)


def matches_the_command_line(browser, command, tmp_path):
    """Renders `command` (the page's "Copy CLI command") and waits for the page's canvas to
    show that image, to 1 in 200 of its values: the frame's PNG follows its line, and on a
    busy machine it may be drawn a while after (a fixed half-second wait failed once in CI).
    (differing values, the largest difference, values)."""
    out = tmp_path / "view.png"
    args = [BIN, "-q", *[str(out) if a == "view.png" else a for a in shlex.split(command)[1:]]]
    subprocess.run(args, check=True)
    png = base64.b64encode(out.read_bytes()).decode()
    last = []

    def same():
        differ, most, values, canvas_values = browser.execute_async_script(COMPARE, png)
        last[:] = [differ, most, values, canvas_values]
        return values == canvas_values and differ <= values // 200

    try:
        wait_for(same, seconds=10)
    except AssertionError:
        raise AssertionError(f"{command}: {last[0]} of {last[2]} values differ (canvas {last[3]} values)") from None
    return last[0], last[1], last[2]

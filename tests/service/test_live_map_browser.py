"""The live map in a real browser: headless Chromium (Debian's chromium and chromium-driver),
driven over the W3C WebDriver protocol with the standard library only. The page is served by
the harness while a scripted device streams ranges; the test checks what the page renders:
one SVG node per node with its label, 2-sigma ellipses and links, the health panel's counters,
a server-sent update changing the DOM, and a node's SoG components after a click.
"""
from __future__ import annotations

import json
import os
import pathlib
import shutil
import subprocess
import tempfile
import urllib.error
import urllib.request

import pytest

from service_support import DEADLOCK_GUARD_S, NODES, OWN, FakeDevice, Harness, free_port, wait_until



class WebDriver:
    """Just enough of W3C WebDriver: a session, navigation, scripts, a screenshot."""

    def __init__(self):
        binary = shutil.which("chromedriver")
        if binary is None:
            pytest.fail("chromedriver missing: scripts/setup.sh installs Debian's chromium-driver")
        self.port = free_port()
        self.profile = tempfile.mkdtemp(prefix="cdro-chromium-")
        self.process = subprocess.Popen([binary, f"--port={self.port}"], stdout=subprocess.DEVNULL,
                                        stderr=subprocess.DEVNULL)
        wait_until(lambda: self._ready(), "chromedriver")
        args = ["--headless=new", "--disable-gpu", "--no-first-run", "--disable-background-networking",
                "--disable-component-update", "--disable-sync", "--disable-dev-shm-usage",
                f"--user-data-dir={self.profile}", "--window-size=1280,900"]
        if os.geteuid() == 0:
            args.append("--no-sandbox")  # Chromium refuses to run as root with its sandbox
        capabilities = {"capabilities": {"alwaysMatch": {"browserName": "chrome", "goog:chromeOptions": {
            "binary": shutil.which("chromium") or "/usr/bin/chromium", "args": args}}}}
        self.session = self._call("POST", "/session", capabilities)["sessionId"]

    def _ready(self) -> bool:
        try:
            return bool(self._call("GET", "/status")["ready"])
        except (urllib.error.URLError, ConnectionError):
            return False

    def _call(self, method: str, path: str, body=None):
        data = None if body is None else json.dumps(body).encode()
        request = urllib.request.Request(f"http://127.0.0.1:{self.port}{path}", data=data, method=method,
                                         headers={"Content-Type": "application/json"})
        with urllib.request.urlopen(request, timeout=60) as response:
            return json.loads(response.read())["value"]

    def get(self, url: str) -> None:
        self._call("POST", f"/session/{self.session}/url", {"url": url})

    def run(self, script: str, *args):
        return self._call("POST", f"/session/{self.session}/execute/sync", {"script": script, "args": list(args)})

    def screenshot(self, path: pathlib.Path) -> None:
        import base64
        path.write_bytes(base64.b64decode(self._call("GET", f"/session/{self.session}/screenshot")))

    def wait(self, script: str, what: str):
        return wait_until(lambda: self.run(script), what, poll_s=0.05)

    def close(self) -> None:
        try:
            self._call("DELETE", f"/session/{self.session}")
        except Exception:  # noqa: BLE001 - best effort: the process is killed below anyway
            pass
        self.process.terminate()
        try:
            self.process.wait(timeout=DEADLOCK_GUARD_S)
        except subprocess.TimeoutExpired:
            self.process.kill()
        shutil.rmtree(self.profile, ignore_errors=True)


@pytest.fixture
def browser():
    driver = WebDriver()
    yield driver
    driver.close()


def test_live_map_renders_and_follows_updates(build_dir, tmp_path, browser):
    link = tmp_path / "ttyPOZYX"
    device = FakeDevice(link)
    harness = Harness(build_dir, tmp_path, device=link, nodes=NODES)
    device.boot()
    harness.wait_connected()
    # Ranges among the own node and two remote nodes; the third remote node stays silent.
    for i in range(30):
        device.range_frame(OWN, NODES[i % 2], 4000 + i)
    device.range_frame(NODES[0], NODES[1], 3500)
    harness.wait_health(lambda h: h["counters"]["frames_delivered"] >= 31, "ranges delivered")

    browser.get(f"http://127.0.0.1:{harness.port}/")
    browser.wait("return document.querySelectorAll('#nodes g.node').length === 3", "three nodes drawn")
    labels = browser.run("return [...document.querySelectorAll('#nodes g.node text')].map(t => t.textContent)")
    assert sorted(labels) == ["0x6000", "0x6069", "0x6A11"]
    assert browser.run("return document.querySelectorAll('#ellipses ellipse.sigma2').length") == 3
    links = browser.run("return [...document.querySelectorAll('#links line.link')]"
                        ".map(l => [+l.dataset.a, +l.dataset.b].join('-'))")
    assert sorted(links) == sorted([f"{OWN}-{NODES[0]}", f"{OWN}-{NODES[1]}", f"{NODES[0]}-{NODES[1]}"])
    # Converged nodes (10+ ranges in the harness) are marked; the health panel shows counters.
    assert browser.run("return document.querySelectorAll('#nodes g.node.converged').length") == 3
    assert browser.run("return document.getElementById('link-state').textContent") == "connected"
    browser.wait("return +document.querySelector('#counters tr[data-counter=\"frames_delivered\"] td.value')"
                 ".textContent >= 31", "counters in the health panel")
    assert browser.run("return document.querySelector('#rates tr[data-rate=\"frames_per_s\"]') !== null")
    browser.wait("return document.getElementById('stream').textContent === 'open'", "event stream open")

    # A server-sent update changes the DOM: the silent node starts ranging, a fourth node appears.
    updates_before = int(browser.run("return document.getElementById('update-count').textContent"))
    for i in range(5):
        device.range_frame(OWN, NODES[2], 2500 + i)
    browser.wait("return document.querySelectorAll('#nodes g.node').length === 4", "the fourth node via SSE")
    assert int(browser.run("return document.getElementById('update-count').textContent")) > updates_before
    # It has one link (to the own node): it hangs on it, and the map says so (dashed, tooltip).
    foldable = browser.run("return [...document.querySelectorAll('#nodes g.node.foldable')].map(g => +g.dataset.id)")
    assert foldable == [NODES[2]]
    tooltip = browser.run(f"return document.querySelector('#nodes g.node[data-id=\"{NODES[2]}\"] title').textContent")
    assert "side is undecided" in tooltip
    assert browser.run(f"return document.querySelector('#nodes g.node[data-id=\"{NODES[2]}\"]').dataset.reason") == \
        "foldable"
    assert browser.run(f"return getComputedStyle(document.querySelector('#nodes g.node[data-id=\"{NODES[2]}\"] "
                       "circle')).strokeDasharray") not in ("", "none")

    # A click fetches the node's SoG components and draws them.
    browser.run(f"document.querySelector('#nodes g.node[data-id=\"{NODES[0]}\"]')"
                ".dispatchEvent(new MouseEvent('click', {bubbles: true}))")
    browser.wait("return document.querySelectorAll('#components ellipse.component').length > 0", "components")
    # Node 0x6069 has links to the own node and to 0x6A11: two rings of 8 components.
    assert browser.run("return document.querySelectorAll('#components ellipse.component').length") == 16
    assert "16 components" in browser.run("return document.getElementById('selection-text').textContent")
    browser.screenshot(pathlib.Path(os.environ.get("CDRO_SCREENSHOT", tmp_path / "live-map.png")))

    # The device goes away: the page says so and keeps the map.
    device.vanish()
    browser.wait("return document.getElementById('link-state').textContent === 'disconnected'", "disconnected")
    assert browser.run("return document.querySelectorAll('#nodes g.node').length") == 4
    assert harness.stop() == 0

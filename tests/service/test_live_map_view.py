"""The live map's view in headless Chromium, checked against what the service sent: node markers
drawn where the page's view transform puts /api/map's positions (read back from a screenshot),
the scale bar as long as its label at the current zoom, zoom (buttons, wheel about the cursor)
and pan (drag) changing the transform and the drawing with it, the floor-plan image under the
map in its place and orientation, links coloured by their residual (a link that reads long is
red, in the picture and in the links table), the robot's trail, and the 2-sigma history chart.
The harness lays 3 nodes out on a 5 m circle (8.660 m apart); the device's ranges decide the
residuals. A floor plan that is missing or not a PNG stops the service at start with its key.
"""
from __future__ import annotations

import io
import json
import math
import os
import pathlib
import socket
import urllib.error
import urllib.request

import pytest

from service_support import NODES, OWN, FakeDevice, Harness, free_udp_port, wait_until
from test_live_map_browser import WebDriver

SIDE_M = 5.0 * math.sqrt(3.0)                  # m between nodes on the harness's 5 m circle
NLOS = (NODES[0], NODES[1])                   # this link reads 2.34 m long
NLOS_RANGE_MM = 11000
CONVERGED_RGB = (0x2E, 0x85, 0x40)            # .node.converged circle
RESIDUAL_BAD_RGB = (0xB5, 0x2B, 0x27)         # .link.residual-bad
PLAN_LOW_LEFT_RGB = (60, 120, 220)            # the floor plan's bottom-left quadrant
PLAN_REST_RGB = (250, 235, 170)               # the rest of it
PLAN_PX = 360                                 # a square image ...
PLAN_M_PER_PX = 0.05                          # ... 18 m wide
PLAN_ORIGIN_M = (-9.0, -9.0)                  # its bottom-left corner: the quadrants meet at (0, 0)


def floor_plan_png(path: pathlib.Path) -> None:
    from PIL import Image
    image = Image.new("RGB", (PLAN_PX, PLAN_PX), PLAN_REST_RGB)
    half = PLAN_PX // 2
    image.paste(PLAN_LOW_LEFT_RGB, (0, half, half, PLAN_PX))   # image rows grow downwards
    image.save(path)


@pytest.fixture
def browser():
    driver = WebDriver()
    yield driver
    driver.close()


def screenshot(browser):
    import base64
    from PIL import Image
    data = base64.b64decode(browser._call("GET", f"/session/{browser.session}/screenshot"))
    return Image.open(io.BytesIO(data)).convert("RGB")


def view(browser) -> dict:
    """The transform the page says it draws with, and where its SVG is on the screen."""
    return browser.run("""
        const svg = document.getElementById('map'), r = svg.getBoundingClientRect(), m = svg.getScreenCTM();
        return {scale: +svg.dataset.scalePxPerM, cx: +svg.dataset.centerXM, cy: +svg.dataset.centerYM,
                left: r.left, top: r.top, width: r.width, height: r.height, dpr: window.devicePixelRatio,
                ctm: [m.a, m.b, m.c, m.d, m.e, m.f], follow: window.cdroLiveMap.view().follow};""")


def to_screen(v: dict, x_m: float, y_m: float) -> tuple[float, float]:
    """World metres to screenshot pixels: the page's transform to the 800 x 600 viewBox (computed
    here), then the browser's from the viewBox to the screen (the SVG's screen CTM)."""
    px = 400 + (x_m - v["cx"]) * v["scale"]
    py = 300 - (y_m - v["cy"]) * v["scale"]
    a, b, c, d, e, f = v["ctm"]
    return ((a * px + c * py + e) * v["dpr"], (b * px + d * py + f) * v["dpr"])


def colour_near(image, xy, rgb, tolerance=40, radius=1) -> bool:
    """Whether most pixels of a small patch around xy have the colour rgb."""
    x, y = round(xy[0]), round(xy[1])
    hits = total = 0
    for dx in range(-radius, radius + 1):
        for dy in range(-radius, radius + 1):
            total += 1
            pixel = image.getpixel((x + dx, y + dy))
            hits += all(abs(p - q) <= tolerance for p, q in zip(pixel, rgb))
    return hits * 2 > total


def map_nodes(harness) -> dict[int, tuple[float, float]]:
    snapshot = harness.api("/api/map")
    return {n["id"]: (n["x_m"], n["y_m"]) for n in snapshot["nodes"] if n["placed"]}


def inside_view(v: dict, x_m: float, y_m: float, margin_px: float = 10) -> bool:
    px, py = 400 + (x_m - v["cx"]) * v["scale"], 300 - (y_m - v["cy"]) * v["scale"]
    return margin_px <= px <= 800 - margin_px and margin_px <= py <= 600 - margin_px


def assert_markers_where_the_transform_says(browser, harness, expect_all: bool = True):
    """Every node inside the view has its marker where the transform puts it (the SVG clips the
    others); returns the view and the screenshot."""
    v = view(browser)
    image = screenshot(browser)
    nodes = map_nodes(harness)
    assert len(nodes) == 3
    shown = {i: xy for i, xy in nodes.items() if inside_view(v, *xy)}
    assert len(shown) == 3 if expect_all else len(shown) >= 1
    for node_id, (x, y) in shown.items():
        at = to_screen(v, x, y)
        assert colour_near(image, at, CONVERGED_RGB), \
            f"no marker of node 0x{node_id:04X} at {at} ({image.getpixel(tuple(map(round, at)))})"
    return v, image


def test_live_map_view_transform_scale_bar_zoom_pan_floor_plan_and_residuals(harness_bin, tmp_path, browser):
    plan = tmp_path / "plan.png"
    floor_plan_png(plan)
    odometry_port = free_udp_port()
    link = tmp_path / "ttyPOZYX"
    device = FakeDevice(link)
    harness = Harness(harness_bin, tmp_path, device=link, nodes=NODES, extra_config=f"""
odometry: {{udp_port: {odometry_port}}}
web:
  floor_plan:
    path: {plan}
    metres_per_pixel: {PLAN_M_PER_PX}
    origin_x_m: {PLAN_ORIGIN_M[0]}
    origin_y_m: {PLAN_ORIGIN_M[1]}
""")
    device.boot()
    harness.wait_connected()
    # 10+ ranges per node (converged in the harness); two links as the circle says, one long.
    for i in range(12):
        device.range_frame(OWN, NODES[0], round(SIDE_M * 1000) + (i % 3) - 1)
        device.range_frame(OWN, NODES[1], round(SIDE_M * 1000) + (i % 3) - 1)
        device.range_frame(NODES[0], NODES[1], NLOS_RANGE_MM + 10 * (i % 3))
    harness.wait_health(lambda h: h["counters"]["frames_delivered"] >= 36, "ranges delivered")

    # The service's residuals: the median range minus the distance between the map's positions.
    snapshot = harness.api("/api/map")
    positions = {n["id"]: (n["x_m"], n["y_m"]) for n in snapshot["nodes"]}
    for edge in snapshot["links"]:
        fitted = math.dist(positions[edge["a"]], positions[edge["b"]])
        assert edge["fitted_distance_m"] == pytest.approx(fitted, abs=1e-9)
        assert edge["residual_m"] == pytest.approx(edge["range_median_m"] - fitted, abs=1e-9)
        expected_median = (NLOS_RANGE_MM + 10) / 1000 if (edge["a"], edge["b"]) == NLOS else round(SIDE_M * 1000) / 1000
        assert edge["range_median_m"] == pytest.approx(expected_median, abs=1e-9)
    assert all(isinstance(n["t_updated_unix_s"], float) and n["t_updated_unix_s"] <= snapshot["t_unix_s"]
               for n in snapshot["nodes"])
    floor = harness.api("/api/floor-plan")
    assert (floor["width_px"], floor["height_px"], floor["metres_per_pixel"]) == (PLAN_PX, PLAN_PX, PLAN_M_PER_PX)
    assert (floor["origin_x_m"], floor["origin_y_m"], floor["rotation_rad"]) == (*PLAN_ORIGIN_M, 0.0)
    with urllib.request.urlopen(f"http://127.0.0.1:{harness.port}{floor['url']}", timeout=5) as response:
        assert response.headers["Content-Type"] == "image/png"
        assert response.read() == plan.read_bytes()

    browser.get(f"http://127.0.0.1:{harness.port}/")
    browser.wait("return document.querySelectorAll('#nodes g.node.converged').length === 3", "three converged nodes")
    browser.wait("return document.getElementById('floor-plan') !== null", "the floor plan's image element")
    browser.wait("return document.getElementById('stream').textContent === 'open'", "event stream open")

    # Markers where the page's transform puts the service's positions (pixels of a screenshot).
    v, image = assert_markers_where_the_transform_says(browser, harness)
    assert v["follow"] is True

    # The floor plan is drawn under the map, bottom-left quadrant where x < 0 and y < 0.
    wait_until(lambda: colour_near(screenshot(browser), to_screen(view(browser), -1.3, -1.3), PLAN_LOW_LEFT_RGB,
                                   tolerance=12, radius=2), "the floor plan's image drawn")
    image = screenshot(browser)
    assert colour_near(image, to_screen(v, 1.3, 1.3), PLAN_REST_RGB, tolerance=12, radius=2)
    assert colour_near(image, to_screen(v, -1.3, 1.3), PLAN_REST_RGB, tolerance=12, radius=2)
    assert colour_near(image, to_screen(v, 1.3, -1.3), PLAN_REST_RGB, tolerance=12, radius=2)

    # Links coloured by residual: the long one red in the picture, the others green.
    classes = browser.run("return Object.fromEntries([...document.querySelectorAll('#links line.link')]"
                          ".map(l => [l.dataset.a + '-' + l.dataset.b, l.getAttribute('class')]))")
    assert classes == {f"{OWN}-{NODES[0]}": "link residual-ok", f"{OWN}-{NODES[1]}": "link residual-ok",
                       f"{NODES[0]}-{NODES[1]}": "link residual-bad"}
    a, b = (to_screen(v, *positions[i]) for i in NLOS)
    assert colour_near(image, ((a[0] + b[0]) / 2, (a[1] + b[1]) / 2), RESIDUAL_BAD_RGB)
    a, b = (to_screen(v, *positions[i]) for i in (OWN, NODES[0]))
    assert not colour_near(image, ((a[0] + b[0]) / 2, (a[1] + b[1]) / 2), RESIDUAL_BAD_RGB)
    first_row = browser.run("return [...document.querySelectorAll('#links-table tbody tr')[0].children]"
                            ".map(td => td.textContent)")
    assert first_row[0] == f"0x{NLOS[0]:04X} – 0x{NLOS[1]:04X}"
    assert float(first_row[3]) == pytest.approx(NLOS_RANGE_MM / 1000 + 0.01 - SIDE_M, abs=2e-3)

    # The scale bar: its line is as long as its label says at the view's scale, on screen too.
    label_m = float(browser.run("return document.getElementById('scale-bar-label').textContent").split()[0])
    line = browser.run("const l = document.getElementById('scale-bar-line');"
                       "return [+l.getAttribute('x1'), +l.getAttribute('x2'), +l.getAttribute('y1')]")
    assert line[1] - line[0] == pytest.approx(label_m * v["scale"], abs=1e-6)
    assert 60 <= line[1] - line[0] <= 150
    row_y = round((v["ctm"][3] * line[2] + v["ctm"][5]) * v["dpr"])
    right_half = range(round((v["left"] + v["width"] / 2) * v["dpr"]), round((v["left"] + v["width"]) * v["dpr"]))
    dark = [x for x in right_half if colour_near(image, (x, row_y), (0x1D, 0x23, 0x30), tolerance=50, radius=0)]
    drawn_px = max(dark) - min(dark)
    assert drawn_px == pytest.approx(label_m * v["scale"] * v["ctm"][0] * v["dpr"], abs=3)

    # Zoom with the button: the scale 1.5 x, the centre kept, the markers follow.
    browser.run("document.getElementById('zoom-in').click()")
    zoomed = view(browser)
    assert zoomed["scale"] == pytest.approx(1.5 * v["scale"]) and zoomed["follow"] is False
    assert (zoomed["cx"], zoomed["cy"]) == pytest.approx((v["cx"], v["cy"]))
    assert_markers_where_the_transform_says(browser, harness, expect_all=False)
    new_label_m = float(browser.run("return document.getElementById('scale-bar-label').textContent").split()[0])
    new_line = browser.run("const l = document.getElementById('scale-bar-line');"
                           "return +l.getAttribute('x2') - +l.getAttribute('x1')")
    assert new_line == pytest.approx(new_label_m * zoomed["scale"], abs=1e-6)

    # Zoom with the wheel about the cursor: the node under it stays under it.
    target = positions[NODES[0]]
    before = to_screen(zoomed, *target)
    browser.run("const [x, y] = arguments;"
                "document.getElementById('map').dispatchEvent(new WheelEvent('wheel', "
                "{clientX: x, clientY: y, deltaY: -200, bubbles: true, cancelable: true}))",
                before[0] / zoomed["dpr"], before[1] / zoomed["dpr"])
    wheeled = view(browser)
    assert wheeled["scale"] > zoomed["scale"] * 1.2
    assert to_screen(wheeled, *target) == pytest.approx(before, abs=0.5)

    # Pan by dragging 100 px to the right and 50 px down: the world moves with the pointer.
    start = (v["left"] + v["width"] / 2, v["top"] + v["height"] / 2)
    browser.run("""const [x, y] = arguments, svg = document.getElementById('map');
        const event = (type, dx, dy) => svg.dispatchEvent(new PointerEvent(type,
            {clientX: x + dx, clientY: y + dy, button: 0, pointerId: 1, isPrimary: true, bubbles: true}));
        event('pointerdown', 0, 0); event('pointermove', 50, 25);
        event('pointermove', 100, 50); event('pointerup', 100, 50);""",
                *start)
    panned = view(browser)
    metres_per_css_px = 1 / (v["ctm"][0] * wheeled["scale"])
    assert panned["scale"] == pytest.approx(wheeled["scale"])
    assert panned["cx"] == pytest.approx(wheeled["cx"] - 100 * metres_per_css_px, abs=1e-6)
    assert panned["cy"] == pytest.approx(wheeled["cy"] + 50 * metres_per_css_px, abs=1e-6)

    # A map update does not undo the user's view.
    updates = int(browser.run("return document.getElementById('update-count').textContent"))
    for _ in range(3):
        device.range_frame(OWN, NODES[0], round(SIDE_M * 1000))
    browser.wait(f"return +document.getElementById('update-count').textContent > {updates}", "an update")
    assert view(browser)["cx"] == pytest.approx(panned["cx"])
    assert view(browser)["scale"] == pytest.approx(panned["scale"])

    # "fit" follows the map again: the first transform, and the markers in place.
    browser.run("document.getElementById('zoom-fit').click()")
    fitted = view(browser)
    # (the fit leaves room for the 2-sigma ellipses, which shrank a little meanwhile)
    assert fitted["follow"] is True and fitted["scale"] == pytest.approx(v["scale"], rel=0.02)
    assert_markers_where_the_transform_says(browser, harness)

    # The robot's trail: odometry moves the device's own node along +x, the page keeps its path.
    steps = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for k in range(6):
        steps.sendto(json.dumps({"distance_m": 0.5, "dheading_rad": 0.0}).encode(), ("127.0.0.1", odometry_port))
        # Each pose reaches the page before the next step, so its trail has every one.
        browser.wait("const t = document.querySelector('#robot polygon title');"
                     f"return t !== null && t.textContent.includes('x {0.5 * (k + 1):.3f} m')", f"robot step {k + 1}")
    steps.close()
    browser.wait("const t = document.querySelector('#trails polyline.robot-trail');"
                 "return t !== null && t.points.numberOfItems >= 6", "the robot's trail")
    robot = harness.api("/api/map")["robot"]
    browser.wait(f"const p = document.querySelector('#trails polyline.robot-trail').points;"
                 f"return Math.abs(p.getItem(p.numberOfItems - 1).x - "
                 f"(400 + ({robot['x_m']} - +document.getElementById('map').dataset.centerXM) * "
                 f"+document.getElementById('map').dataset.scalePxPerM)) < 1e-3", "the trail ends at the robot")
    trail_y = browser.run("const p = document.querySelector('#trails polyline.robot-trail').points;"
                          "return [...Array(p.numberOfItems).keys()].map(i => p.getItem(i).y)")
    now = view(browser)
    assert trail_y == pytest.approx([300 - (0.0 - now["cy"]) * now["scale"]] * len(trail_y), abs=1e-3)

    # A moving node's trail: the page is handed maps in which 0x6069 moves (the harness's nodes
    # never move), and keeps where it went, drawn through the same transform (held still by a
    # zoom, so that the maps the service sends meanwhile do not refit it).
    browser.run("document.getElementById('zoom-in').click()")
    moved = [(positions[NODES[0]][0] + 0.5 * k, positions[NODES[0]][1] - 0.25 * k) for k in range(4)]
    browser.run("""const [id, path] = arguments;
        fetch('/api/map').then(r => r.json()).then(map => {
          for (const [x, y] of path) {
            const copy = JSON.parse(JSON.stringify(map));
            const node = copy.nodes.find(n => n.id === id);
            Object.assign(node, {x_m: x, y_m: y, moving: true, status: 'moving'});
            onMap(copy);
          }
          window.trailDone = true;
        });""", NODES[0], moved)
    browser.wait("return window.trailDone === true", "the synthetic maps")
    trail = browser.run("const p = document.querySelector("
                        f"'#trails polyline.node-trail[data-id=\"{NODES[0]}\"]').points;"
                        "return [...Array(p.numberOfItems).keys()].map(i => [p.getItem(i).x, p.getItem(i).y])")
    now = view(browser)
    expected = [[400 + (x - now["cx"]) * now["scale"], 300 - (y - now["cy"]) * now["scale"]] for x, y in moved]
    assert [c for point in trail for c in point] == pytest.approx([c for point in expected for c in point], abs=1e-3)
    assert browser.run("return document.querySelectorAll('#trails polyline.node-trail').length") == 1
    browser.run("document.getElementById('zoom-fit').click()")

    # The 2-sigma chart: a line per node; the selected one drawn on top, its radius shrinking
    # as its ranges add up (the harness's variance is 1 / (1 + ranges)).
    browser.run(f"document.querySelector('#nodes g.node[data-id=\"{NODES[0]}\"]')"
                ".dispatchEvent(new MouseEvent('click', {bubbles: true}))")
    for i in range(6):
        device.range_frame(OWN, NODES[0], round(SIDE_M * 1000))
        browser.wait(f"const l = document.querySelector('#sigma-chart polyline.sigma-line.selected');"
                     f"return l !== null && l.points.numberOfItems >= {2 + i // 2}", "a longer history")
    assert browser.run("return document.querySelector('#sigma-chart polyline.selected').dataset.id") == str(NODES[0])
    assert browser.run("return document.querySelectorAll('#sigma-chart polyline.sigma-line').length") == 3
    browser.screenshot(pathlib.Path(os.environ.get("CDRO_SCREENSHOT_VIEW", tmp_path / "live-map-view.png")))
    ys = browser.run("const p = document.querySelector('#sigma-chart polyline.selected').points;"
                     "return [...Array(p.numberOfItems).keys()].map(i => p.getItem(i).y)")
    assert all(later >= earlier - 1e-9 for earlier, later in zip(ys, ys[1:])) and ys[-1] > ys[0]
    assert harness.stop() == 0


@pytest.mark.parametrize("content, message", [
    (None, "web.floor_plan.path: cannot read"),
    (b"GIF89a not a png at all, just some bytes", "is not a PNG image"),
])
def test_a_floor_plan_that_cannot_be_used_stops_the_service_at_start(harness_bin, tmp_path, content, message):
    plan = tmp_path / "plan.png"
    if content is not None:
        plan.write_bytes(content)
    harness = Harness(harness_bin, tmp_path, extra_config=f"web: {{floor_plan: {{path: {plan}}}}}\n")
    assert harness.wait_exit() == 2
    assert message in harness.log() and str(plan) in harness.log()


def test_without_a_floor_plan_the_api_says_so(harness_bin, tmp_path):
    harness = Harness(harness_bin, tmp_path)
    wait_until(lambda: harness.api("/api/map") is not None, "the live map")
    with pytest.raises(urllib.error.HTTPError) as error:
        urllib.request.urlopen(f"http://127.0.0.1:{harness.port}/api/floor-plan", timeout=5)
    assert error.value.code == 404 and b"web.floor_plan.path" in error.value.read()
    assert harness.stop() == 0

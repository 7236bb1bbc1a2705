"""The 3D replay in a real Chromium: on the server's page and in ``robobpp view``'s offline page."""

from __future__ import annotations

import base64
import json
from pathlib import Path

import pytest

from robobpp.client.serve import BackgroundServer
from robobpp.core import Box, ContainerSpec, EpisodeSpec
from robobpp.episode import run_episode
from robobpp.policies import load_policy
from robobpp.web.trace import episodes_from, read_trace
from robobpp.web.viewer import render_standalone, view_app
from tests.web.conftest import PageProbe, Server

pytestmark = pytest.mark.browser


def canvas_image(probe: PageProbe) -> str:
    """A PNG screenshot of the 3D canvas, as a data URL."""
    png = probe.page.locator("[data-role=canvas]").screenshot()
    return "data:image/png;base64," + base64.b64encode(png).decode()


def changed_fraction(probe: PageProbe, a: str, b: str) -> float:
    """Share of pixels that differ noticeably between two screenshots (decoded by the browser itself)."""
    return probe.page.evaluate(
        """async ([a, b]) => {
            const load = (src) => new Promise((ok, fail) => {
                const img = new Image(); img.onload = () => ok(img); img.onerror = fail; img.src = src; });
            const [ia, ib] = await Promise.all([load(a), load(b)]);
            const pixels = (img) => {
                const c = document.createElement("canvas");
                c.width = img.width; c.height = img.height;
                const g = c.getContext("2d"); g.drawImage(img, 0, 0);
                return g.getImageData(0, 0, img.width, img.height).data;
            };
            if (ia.width !== ib.width || ia.height !== ib.height) return 1;
            const pa = pixels(ia), pb = pixels(ib);
            let changed = 0;
            for (let i = 0; i < pa.length; i += 4) {
                const d = Math.abs(pa[i] - pb[i]) + Math.abs(pa[i + 1] - pb[i + 1]) + Math.abs(pa[i + 2] - pb[i + 2]);
                if (d > 30) changed += 1;
            }
            return changed / (pa.length / 4);
        }""",
        [a, b],
    )


def check_viewer(probe: PageProbe, steps: int) -> None:
    """Final frame draws boxes, the empty frame does not, the slider and buttons move the step."""
    page = probe.page
    page.wait_for_function("() => document.querySelector('[data-replay]').dataset.frame !== undefined")
    root = page.locator("[data-replay]")
    assert root.get_attribute("data-frame") == str(steps)
    assert int(root.get_attribute("data-boxes") or 0) > 0
    assert page.locator("[data-role=label]").inner_text() == f"Step {steps} / {steps}"
    full = canvas_image(probe)
    page.locator("[data-role=slider]").fill("0")
    assert root.get_attribute("data-frame") == "0" and root.get_attribute("data-boxes") == "0"
    empty = canvas_image(probe)
    assert changed_fraction(probe, full, empty) > 0.01, "the final frame looks like the empty scene"
    middle = max(1, steps // 2)
    page.locator("[data-role=slider]").fill(str(middle))
    assert page.locator("[data-role=label]").inner_text() == f"Step {middle} / {steps}"
    assert root.get_attribute("data-frame") == str(middle)
    assert 0 < int(root.get_attribute("data-boxes") or 0) <= middle
    assert changed_fraction(probe, canvas_image(probe), empty) > 0.002
    page.locator("[data-role=next]").click()
    assert root.get_attribute("data-frame") == str(middle + 1)
    page.locator("[data-role=prev]").click()
    page.locator("[data-role=prev]").click()
    assert page.locator("[data-role=slider]").input_value() == str(middle - 1)
    page.locator("[data-role=last]").click()
    assert root.get_attribute("data-frame") == str(steps)


def test_server_replay_page(server: Server, probe: PageProbe) -> None:
    sid = server.ids["public"]
    episodes = server.get(f"/api/v1/submissions/{sid}/episodes").json()
    physics = next(e for e in episodes if e["setting"] == "physics" and e["has_trace"])
    probe.page.goto(f"{server.url}/submissions/{sid}/episodes/{physics['id']}/replay")
    check_viewer(probe, physics["boxes_placed"])
    info = probe.page.locator("[data-role=episode-info]").inner_text()
    assert "physics" in info and "Static stability" in info
    probe.shot("replay")
    probe.assert_clean()


def test_replay_play_button_advances(server: Server, probe: PageProbe) -> None:
    sid = server.ids["public"]
    ep = server.get(f"/api/v1/submissions/{sid}/episodes").json()[0]
    probe.page.goto(f"{server.url}/submissions/{sid}/episodes/{ep['id']}/replay")
    probe.page.locator("[data-role=first]").click()
    probe.page.locator("[data-role=play]").click()
    assert probe.page.locator("[data-role=play]").inner_text() == "Pause"
    probe.page.wait_for_function("() => Number(document.querySelector('[data-replay]').dataset.frame) >= 2")
    probe.page.locator("[data-role=play]").click()
    assert probe.page.locator("[data-role=play]").inner_text() == "Play"
    probe.assert_clean()


@pytest.fixture(scope="module")
def trace_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A trace as `robobpp evaluate --trace` writes it: two real Math Pack episodes."""
    rng = __import__("random").Random(3)
    episodes = []
    for group, container in enumerate([ContainerSpec(134, 125, 100), ContainerSpec(250, 120, 100)]):
        boxes = tuple(
            Box(rng.randint(20, 60), rng.randint(20, 50), rng.randint(10, 40), 5.0) for _ in range(40)
        )
        spec = EpisodeSpec("repetitive", "train", group, boxes, container, 7.0, 0)
        episodes.append(run_episode(spec, load_policy("dbl"), "math").to_dict())
    path = tmp_path_factory.mktemp("trace") / "out.json"
    path.write_text(json.dumps({"policy": "dbl", "episodes": episodes}))
    return path


def test_robobpp_view_writes_a_self_contained_page(
    trace_file: Path, tmp_path: Path, probe: PageProbe
) -> None:
    from typer.testing import CliRunner

    from robobpp.cli import _register, app

    _register()
    out = tmp_path / "viewer.html"
    result = CliRunner().invoke(app, ["view", str(trace_file), "--output", str(out), "--no-open"])
    assert result.exit_code == 0, result.output
    assert out.as_uri() in result.output
    html = out.read_text()
    assert "/static/" not in html  # nothing to fetch: it opens from disk
    probe.page.route("**/*", lambda route: route.abort() if not route.request.url.startswith(("file:", "data:"))
                     else route.continue_())  # fmt: skip
    probe.page.goto(out.as_uri())
    steps = len(read_trace(trace_file)[0]["steps"])
    check_viewer(probe, steps)
    assert probe.page.locator("[data-role=episode] option").count() == 2
    probe.page.locator("[data-role=episode]").select_option("1")
    steps2 = len(read_trace(trace_file)[1]["steps"])
    assert probe.page.locator("[data-role=label]").inner_text() == f"Step {steps2} / {steps2}"
    probe.shot("view-offline")
    probe.assert_clean()


def test_robobpp_view_served_page(trace_file: Path, probe: PageProbe) -> None:
    episodes = read_trace(trace_file)
    with BackgroundServer(view_app(episodes, trace_file.name)) as srv:
        probe.page.goto(srv.url + "/")
        check_viewer(probe, len(episodes[0]["steps"]))
    probe.assert_clean()


def test_collapse_and_tool_path_are_drawn(trace_file: Path, tmp_path: Path, probe: PageProbe) -> None:
    """An Execution Pack-shaped trace: a tool path per placement and a collapse at the last step."""
    episode = json.loads(trace_file.read_text())["episodes"][0]
    episode["setting"] = "execution"
    placed = [s for s in episode["steps"] if s["placement"]]
    for s in placed:
        p = s["placement"]
        top = [p["x"] + p["length"] / 2, p["y"] + p["width"] / 2, p["z"] + p["height"]]
        s["extra"] = {"tool_path_cm": [[-80.0, 60.0, 120.0], [top[0], top[1], 150.0], top]}
        s["trajectory_length_m"] = 2.5
    last = placed[-1]
    last["collapsed"] = True
    last["extra"]["collapsed_boxes"] = [0, 1, last["placement"]["index"]]
    n = episode["steps"].index(last) + 1
    page_file = tmp_path / "exec.html"
    page_file.write_text(render_standalone(episodes_from(episode), source="exec.json"))
    probe.page.goto(page_file.as_uri())
    root = probe.page.locator("[data-replay]")
    probe.page.locator("[data-role=slider]").fill(str(n - 1))
    assert root.get_attribute("data-tool-path") == "3" and root.get_attribute("data-collapsed") == "0"
    before = canvas_image(probe)
    probe.page.locator("[data-role=slider]").fill(str(n))
    assert root.get_attribute("data-collapsed") == "3"
    assert "collapse" in probe.page.locator("[data-role=overlay]").inner_text()
    assert "Collapse" in probe.page.locator("[data-role=step-info]").inner_text()
    assert changed_fraction(probe, before, canvas_image(probe)) > 0.002
    probe.shot("replay-execution")
    probe.assert_clean()

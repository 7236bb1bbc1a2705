"""The 3D replay in a real Chromium: on the server's page and in ``robobpp view``'s offline page."""

from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np
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
    """Opens at step 0 (empty), the last frame draws boxes, the slider and buttons move the step."""
    page = probe.page
    page.wait_for_function("() => document.querySelector('[data-replay]').dataset.frame !== undefined")
    root = page.locator("[data-replay]")
    assert root.get_attribute("data-frame") == "0" and root.get_attribute("data-boxes") == "0"
    assert page.locator("[data-role=label]").inner_text() == f"Step 0 / {steps}"
    empty = canvas_image(probe)
    page.locator("[data-role=last]").click()
    assert root.get_attribute("data-frame") == str(steps)
    assert int(root.get_attribute("data-boxes") or 0) > 0
    assert page.locator("[data-role=label]").inner_text() == f"Step {steps} / {steps}"
    full = canvas_image(probe)
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
    assert root.get_attribute("data-frame") == str(middle - 1)
    page.locator("[data-role=first]").click()
    assert root.get_attribute("data-frame") == "0"


def test_server_replay_page(server: Server, probe: PageProbe) -> None:
    sid = server.ids["public"]
    episodes = server.get(f"/api/v1/submissions/{sid}/episodes").json()
    physics = next(e for e in episodes if e["setting"] == "physics" and e["has_trace"])
    probe.page.goto(f"{server.url}/submissions/{sid}/episodes/{physics['id']}/replay")
    check_viewer(probe, physics["boxes_placed"])
    info = probe.page.locator("[data-role=episode-info]").inner_text()
    assert "physics" in info and "Static stability" in info
    probe.page.locator("[data-role=last]").click()
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

    from robobpp.cli import app, register_commands

    register_commands()
    out = tmp_path / "viewer.html"
    result = CliRunner().invoke(app, ["view", str(trace_file), "--output", str(out), "--no-open"])
    assert result.exit_code == 0, result.output
    assert out.as_uri() in result.output
    html = out.read_text()
    assert "/static/" not in html  # nothing to fetch: it opens from disk
    probe.page.route(
        "**/*",
        lambda route: (
            route.abort() if not route.request.url.startswith(("file:", "data:")) else route.continue_()
        ),
    )
    probe.page.goto(out.as_uri())
    steps = len(read_trace(trace_file)[0]["steps"])
    check_viewer(probe, steps)
    assert probe.page.locator("[data-role=episode] option").count() == 2
    probe.page.locator("[data-role=episode]").select_option("1")
    steps2 = len(read_trace(trace_file)[1]["steps"])
    assert probe.page.locator("[data-role=label]").inner_text() == f"Step 0 / {steps2}"
    probe.shot("view-offline")
    probe.assert_clean()


def test_robobpp_view_served_page(trace_file: Path, probe: PageProbe) -> None:
    episodes = read_trace(trace_file)
    with BackgroundServer(view_app(episodes, trace_file.name)) as srv:
        probe.page.goto(srv.url + "/")
        check_viewer(probe, len(episodes[0]["steps"]))
    probe.assert_clean()


def test_collapse_danger_and_tool_path_are_drawn(trace_file: Path, tmp_path: Path, probe: PageProbe) -> None:
    """An Execution Pack-shaped trace without a robot: a tool path per placement, a dangerous operation and a
    collapse at the last step, both marked on the time line."""
    episode = json.loads(trace_file.read_text())["episodes"][0]
    episode["setting"] = "execution"
    placed = [s for s in episode["steps"] if s["placement"]]
    for s in placed:
        p = s["placement"]
        top = [p["x"] + p["length"] / 2, p["y"] + p["width"] / 2, p["z"] + p["height"]]
        s["extra"] = {"tool_path_cm": [[-80.0, 60.0, 120.0], [top[0], top[1], 150.0], top]}
        s["trajectory_length_m"] = 2.5
        s["dangerous"] = False
    placed[2]["dangerous"] = True
    last = placed[-1]
    last["collapsed"] = True
    last["extra"]["collapsed_boxes"] = [0, 1, last["placement"]["index"]]
    n = episode["steps"].index(last) + 1
    page_file = tmp_path / "exec.html"
    page_file.write_text(render_standalone(episodes_from(episode), source="exec.json"))
    probe.page.goto(page_file.as_uri())
    root = probe.page.locator("[data-replay]")
    assert probe.page.locator("[data-role=timeline] .mark.collapse").count() == 1
    danger = probe.page.locator("[data-role=timeline] .mark.dangerous")
    assert danger.count() == 1
    danger.click()  # a mark takes you to its step
    assert root.get_attribute("data-frame") == str(episode["steps"].index(placed[2]) + 1)
    assert "dangerous" in probe.page.locator("[data-role=overlay]").inner_text()
    probe.page.locator("[data-role=slider]").fill(str(n - 1))
    assert root.get_attribute("data-tool-path") == "3" and root.get_attribute("data-collapsed") == "0"
    before = canvas_image(probe)
    probe.page.locator("[data-role=slider]").fill(str(n))
    assert root.get_attribute("data-collapsed") == "3"
    assert "collapse" in probe.page.locator("[data-role=overlay]").inner_text()
    assert "Collapse" in probe.page.locator("[data-role=step-info]").inner_text()
    assert changed_fraction(probe, before, canvas_image(probe)) > 0.002
    # An episode a collapse ended: its final state names the collapse once ("collapse — collapse!" before).
    episode["termination"] = "collapse"
    episode["steps"][-1]["collapsed"] = True
    page_file.write_text(render_standalone(episodes_from(episode), source="exec.json"))
    probe.page.goto(page_file.as_uri())
    probe.page.locator("[data-role=slider]").fill(str(len(episode["steps"])))
    overlay = probe.page.locator("[data-role=overlay]").inner_text()
    assert "final state" in overlay and overlay.lower().count("collapse") == 1, overlay
    probe.assert_clean()


# -- the robot and the boxes over time -----------------------------------------------------------------------

ARM_PIXELS = """async (src) => {
    // Pixels of the arm's orange (hue 10-40°, saturated, not dark) and their centroid.
    const img = await new Promise((ok, fail) => { const i = new Image(); i.onload = () => ok(i); i.onerror = fail; i.src = src; });
    const c = document.createElement("canvas");
    c.width = img.width; c.height = img.height;
    const g = c.getContext("2d"); g.drawImage(img, 0, 0);
    const d = g.getImageData(0, 0, img.width, img.height).data;
    let count = 0, sx = 0, sy = 0;
    const mask = new Uint8Array(img.width * img.height);
    for (let i = 0; i < d.length; i += 4) {
        const [r, gr, b] = [d[i], d[i + 1], d[i + 2]];
        if (r < 100 || r < gr || gr < b || (r - b) / r < 0.6) continue;
        const hue = (60 * (gr - b)) / (r - b);
        if (hue < 10 || hue > 40) continue;
        const k = i / 4;
        mask[k] = 1; count += 1; sx += k % img.width; sy += Math.floor(k / img.width);
    }
    return { count, cx: sx / Math.max(1, count), cy: sy / Math.max(1, count), mask: Array.from(mask).join("") };
}"""


def arm_pixels(probe: PageProbe) -> dict:
    return probe.page.evaluate(ARM_PIXELS, canvas_image(probe))


def show(probe: PageProbe, step: int, ms_of: str) -> None:
    """Put the replay at ``ms_of`` (a JS expression over the step's motion ``m``) into step ``step``."""
    probe.page.evaluate(
        f"""() => {{ const r = window.robobppReplay, m = r.episode.steps[{step} - 1].motion;
                    r.show({step} - 1 + ({ms_of}) / (r.stepSeconds({step}) * 1000)); }}"""
    )


@pytest.fixture(scope="module")
def execution_page(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """A real Execution Pack episode (DBL, 6 boxes) as `robobpp view --output` writes it."""
    rng = __import__("random").Random(3)
    boxes = tuple(Box(rng.randint(25, 50), rng.randint(20, 40), rng.randint(15, 30), 5.0) for _ in range(6))
    spec = EpisodeSpec("repetitive", "train", 0, boxes, ContainerSpec(120, 100, 100), 7.0, 0)
    episode = json.loads(json.dumps(run_episode(spec, load_policy("dbl"), "execution").to_dict()))
    assert episode["boxes_placed"] == 6
    page_file = tmp_path_factory.mktemp("exec") / "exec.html"
    page_file.write_text(render_standalone(episodes_from(episode), source="exec.json"))
    return page_file, episode


def test_the_execution_replay_shows_the_robot_at_work(
    execution_page: tuple[Path, dict], probe: PageProbe
) -> None:
    from robobpp.sim.execution.recording import Q_SCALE
    from robobpp.sim.robot.kinematics import rot, tcp_pose

    page_file, episode = execution_page
    page = probe.page
    page.goto(page_file.as_uri())
    root = page.locator("[data-replay]")
    page.wait_for_function("() => document.querySelector('[data-replay]').dataset.frame === '0'")
    waiting = arm_pixels(probe)
    assert waiting["count"] > 2000, "no arm at step 0"
    # Mid-transfer of step 1: suction on, the arm elsewhere.
    show(probe, 1, "(m.grip[0] + m.grip[1]) / 2")
    assert root.get_attribute("data-phase") == "transfer" and root.get_attribute("data-suction") == "on"
    assert root.get_attribute("data-frame") == "1"
    moving = arm_pixels(probe)
    assert moving["count"] > 2000
    differ = sum(a != b for a, b in zip(waiting["mask"], moving["mask"], strict=True))
    assert differ > 0.3 * max(waiting["count"], moving["count"]), "the arm did not move"
    assert abs(moving["cx"] - waiting["cx"]) + abs(moving["cy"] - waiting["cy"]) > 10
    # The page's forward kinematics is the simulator's: the cup at the release, from the recorded angles.
    show(probe, 1, "m.grip[1]")
    tcp_js = page.evaluate("() => window.robobppReplay.tcpWorld()")
    m = episode["steps"][0]["extra"]["motion"]
    q = np.array(m["q"]).reshape(-1, 6)[m["t"].index(m["grip"][1])] / Q_SCALE
    base = episode["steps"][0]["extra"]["cell"]["base"]
    tcp_py = (rot("z", base[3]) @ tcp_pose(q)[0] + base[:3]) * 100
    assert np.allclose(tcp_js, tcp_py, atol=0.05), (tcp_js, tcp_py)
    placed = episode["steps"][0]["placement"]
    assert abs(tcp_py[2] - (placed["z"] + placed["height"])) < 1.0  # the cup on the box's top face
    assert root.get_attribute("data-suction") == "off"
    # Play (fast) moves through the steps.
    page.locator("[data-role=speed]").select_option("16")
    page.locator("[data-role=first]").click()
    page.locator("[data-role=play]").click()
    assert page.locator("[data-role=play]").inner_text() == "Pause"
    page.wait_for_function("() => Number(document.querySelector('[data-replay]').dataset.frame) >= 2")
    # Pause. On a loaded machine one animation frame may carry the fast playback to its end (it then stops by
    # itself and this click plays it again): either way, once the button reads "Play" the view stands still.
    page.locator("[data-role=play]").click()
    page.wait_for_function("() => document.querySelector('[data-role=play]').textContent === 'Play'")
    frame = page.evaluate("() => document.querySelector('[data-replay]').dataset.frame")
    page.wait_for_timeout(500)
    assert page.evaluate("() => document.querySelector('[data-replay]').dataset.frame") == frame
    show(probe, 5, "(m.grip[0] + 2 * m.grip[1]) / 3")
    probe.shot("replay-execution")
    probe.assert_clean()


def test_the_physics_replay_shows_boxes_settling(tmp_path: Path, probe: PageProbe) -> None:
    """A row of boxes, then a heavy slab on a thin post: the post topples and the slab falls onto the row."""
    from robobpp.core import Action
    from robobpp.episode import Episode
    from robobpp.sim.physics import PhysicsPack

    spec = EpisodeSpec(
        "repetitive",
        "train",
        0,
        (Box(30, 30, 20, 5.0), Box(30, 30, 20, 5.0), Box(8, 30, 50, 1.0), Box(30, 30, 10, 20.0)),
        ContainerSpec(120, 100, 100),
        7.0,
        0,
    )
    episode = Episode(spec, PhysicsPack())
    for action in (Action(0, 0, 0), Action(30, 0, 0), Action(60, 60, 0), Action(53, 60, 0)):
        episode.step(action, 0.0)
    data = json.loads(json.dumps(episode.result("scripted").to_dict()))
    episode.setting.close()
    assert data["termination"] == "collapse" and "track" in data["steps"][3]["extra"]
    page_file = tmp_path / "physics.html"
    page_file.write_text(render_standalone(episodes_from(data), source="physics.json"))
    probe.page.goto(page_file.as_uri())
    root = probe.page.locator("[data-replay]")
    probe.page.wait_for_function("() => document.querySelector('[data-replay]').dataset.frame === '0'")
    probe.page.evaluate("() => window.robobppReplay.show(3.02)")
    assert root.get_attribute("data-phase") == "settle" and root.get_attribute("data-frame") == "4"
    standing = canvas_image(probe)
    probe.page.evaluate("() => window.robobppReplay.show(3.35)")
    falling = canvas_image(probe)
    assert changed_fraction(probe, standing, falling) > 0.003, "nothing moved during the settle"
    probe.page.evaluate("() => window.robobppReplay.show(4)")
    assert changed_fraction(probe, falling, canvas_image(probe)) > 0.001
    assert root.get_attribute("data-collapsed") != "0"
    probe.page.evaluate("() => window.robobppReplay.show(3.35)")
    probe.shot("replay-physics-settle")
    probe.assert_clean()

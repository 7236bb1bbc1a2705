"""The replay of an 80-box Execution Pack episode: trace size and how long the page takes to open.

Runs DBL on one train group of the repetitive dataset in the Execution Pack (group 3 places all 80
boxes) and writes its trace, or reuses ``--trace`` when the file exists (the episode is the slow part).
Then prints the trace's size (JSON, gzip, and per record: robot motion, box tracks, per-step poses) and
opens ``robobpp view``'s self-contained page in Debian's Chromium (headless, software WebGL) to time

- Python: reading + checking the trace and rendering the HTML page;
- the browser: navigation to the replay drawn at step 0 (``data-frame`` set), median of ``--loads``;
- scrubbing: the time to show one position mid-operation (arm, carried box, boxes), median over 200.

- ``--screenshot PNG --at U``: the page at time-line position U (docs/screenshots/replay-execution-80.png).
- ``--overhead``: the episode once more with recording off and on: CPU per box, same outcome or not.

    python bench/bench_replay.py [--trace replay80.json] [--group 3] [--loads 5] [--overhead]
                                  [--screenshot PNG --at 65.45]
"""

from __future__ import annotations

import argparse
import gzip
import json
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from _common import machine

CHROMIUM = "/usr/bin/chromium"


def run(dataset: str, group: int, record: bool) -> tuple[dict[str, Any], float]:
    """The episode's result and its CPU seconds, recording the replay's motion and tracks or not."""
    from robobpp.datasets import episode_specs
    from robobpp.episode import run_episode
    from robobpp.policies import load_policy
    from robobpp.sim.execution import ExecutionPack

    spec = episode_specs(dataset, split="train", groups=group + 1)[group]
    pack = ExecutionPack()
    pack.record_tracks = record
    t0 = time.process_time()
    result = run_episode(spec, load_policy("dbl"), pack).to_dict()
    return result, time.process_time() - t0


def make_trace(path: Path, dataset: str, group: int) -> None:
    result, cpu = run(dataset, group, True)
    print(f"episode: {result['boxes_placed']} boxes placed, {cpu:.1f} CPU s")
    path.write_text(json.dumps({"policy": "dbl", "episodes": [result]}))


def overhead(dataset: str, group: int) -> None:
    """CPU per box with and without recording, and that the outcome is the same."""
    (off, cpu_off), (on, cpu_on) = run(dataset, group, False), run(dataset, group, True)
    # Decision time is wall-clock (the only figure allowed to differ between runs).

    def figures(r: dict[str, Any]) -> tuple[dict[str, Any], Any]:
        return {k: v for k, v in r["metrics"].items() if k != "decision_time"}, r["final"]

    same = figures(off) == figures(on)
    n = max(1, on["boxes_placed"])
    print(
        f"recording: {1000 * cpu_off / n:.0f} ms/box without, {1000 * cpu_on / n:.0f} ms/box with "
        f"({100 * (cpu_on / cpu_off - 1):+.1f} %); same metrics and final poses: {same}"
    )


def sizes(data: dict[str, Any]) -> dict[str, int]:
    steps = data["episodes"][0]["steps"]

    def part(key: str) -> int:
        return sum(len(json.dumps(s["extra"][key])) for s in steps if key in s.get("extra", {}))

    text = json.dumps(data)
    return {
        "json": len(text),
        "gzip": len(gzip.compress(text.encode())),
        "motion": part("motion"),
        "track": part("track"),
        "poses": part("poses"),
        "cell": part("cell"),
        "steps": len(steps),
    }


def screenshot(page_file: Path, out: Path, at: float) -> None:
    """The page at time-line position ``at`` (docs/screenshots)."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--headless", "--no-sandbox"])
        page = browser.new_page(viewport={"width": 1360, "height": 900})
        page.goto(page_file.as_uri())
        page.wait_for_function("() => document.querySelector('[data-replay]').dataset.frame === '0'")
        page.evaluate(f"() => window.robobppReplay.show({at})")
        page.screenshot(path=str(out), full_page=True)
        browser.close()


def browser_times(page_file: Path, loads: int) -> tuple[list[float], list[float]]:
    from playwright.sync_api import Error, sync_playwright

    opened: list[float] = []
    scrub: list[float] = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--headless", "--no-sandbox"])
        for _ in range(loads):
            page = browser.new_page(viewport={"width": 1360, "height": 900})
            errors: list[str] = []

            def on_error(e: Error, errors: list[str] = errors) -> None:
                errors.append(str(e))

            page.on("pageerror", on_error)
            t0 = time.perf_counter()
            page.goto(page_file.as_uri())
            page.wait_for_function("() => document.querySelector('[data-replay]').dataset.frame === '0'")
            opened.append(time.perf_counter() - t0)
            if errors:
                raise SystemExit(f"the page failed: {errors}")
            if not scrub:
                scrub = page.evaluate(
                    """() => {
                        const r = window.robobppReplay, out = [];
                        for (let i = 0; i < 200; i += 1) {
                            const t0 = performance.now();
                            r.show(((i * 0.37) % r.frames) + 0.3);
                            out.push((performance.now() - t0) / 1000);
                        }
                        return out;
                    }"""
                )
            page.close()
        browser.close()
    return opened, scrub


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trace", type=Path, default=Path("replay80.json"))
    ap.add_argument("--dataset", default="repetitive")
    ap.add_argument("--group", type=int, default=3)
    ap.add_argument("--loads", type=int, default=5)
    ap.add_argument("--overhead", action="store_true", help="also run the episode without recording")
    ap.add_argument("--screenshot", type=Path, help="also save the page at time-line position --at here")
    ap.add_argument("--at", type=float, default=65.45)
    args = ap.parse_args()
    if args.overhead:
        overhead(args.dataset, args.group)
    if not args.trace.exists():
        make_trace(args.trace, args.dataset, args.group)
    data = json.loads(args.trace.read_text())
    s = sizes(data)
    print(f"machine: {machine()}")
    print(
        f"trace: {s['steps']} steps, {s['json'] / 1e3:.0f} kB JSON, {s['gzip'] / 1e3:.0f} kB gzip; "
        f"motion {s['motion'] / 1e3:.0f} kB, tracks {s['track'] / 1e3:.0f} kB, poses {s['poses'] / 1e3:.0f} kB, "
        f"cell {s['cell'] / 1e3:.1f} kB"
    )

    from robobpp.web.trace import read_trace
    from robobpp.web.viewer import render_standalone

    t0 = time.perf_counter()
    episodes = read_trace(args.trace)
    t1 = time.perf_counter()
    html = render_standalone(episodes, source=args.trace.name)
    t2 = time.perf_counter()
    payload = len(json.dumps({"episodes": episodes}))
    print(
        f"python: read+check {1000 * (t1 - t0):.0f} ms, render page {1000 * (t2 - t1):.0f} ms; "
        f"page {len(html) / 1e6:.2f} MB (viewer payload {payload / 1e3:.0f} kB)"
    )
    with tempfile.TemporaryDirectory() as tmp:
        page_file = Path(tmp) / "replay.html"
        page_file.write_text(html)
        opened, scrub = browser_times(page_file, args.loads)
        if args.screenshot is not None:
            screenshot(page_file, args.screenshot, args.at)
    print(
        f"browser: open to step 0 drawn, median of {len(opened)}: {statistics.median(opened):.2f} s "
        f"(min {min(opened):.2f}, max {max(opened):.2f}); one scrub position: median "
        f"{1000 * statistics.median(scrub):.1f} ms, p95 {1000 * sorted(scrub)[int(0.95 * len(scrub))]:.1f} ms"
    )


if __name__ == "__main__":
    main()

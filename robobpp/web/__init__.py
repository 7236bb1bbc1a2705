"""Templates, static files and view helpers of the web pages (the server's pages and ``robobpp view``).

One Jinja2 environment serves both, with autoescape on for every template: participant names, policy
names and termination details are user text and must reach the page as text.
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path
from typing import Any

import jinja2

from robobpp.schemas import start_estimate_text
from robobpp.vocabulary import CLOSED, PAPER

WEB_DIR = Path(__file__).resolve().parent
TEMPLATES_DIR = WEB_DIR / "templates"
STATIC_DIR = WEB_DIR / "static"

SETTING_TITLES = {"math": "Math Pack", "physics": "Physics Pack", "execution": "Execution Pack"}
#: How each loop (robobpp.vocabulary.Loop) is labelled wherever a physical setting's figures are shown (docs/web.md).
LOOP_TITLES = {CLOSED: "closed loop (the benchmark)", PAPER: "paper protocol (plan in Math, replay)"}
#: The same, where a table cell has little room (the full title goes in its tooltip).
LOOP_SHORT = {CLOSED: "closed loop", PAPER: "paper protocol"}


def _number(value: Any) -> float | None:
    if value is None or isinstance(value, bool):
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def fmt_num(value: Any, digits: int = 3) -> str:
    """A metric value for a table cell, always with ``digits`` decimals (never scientific notation: an
    interval reads "<0.0001–0.0024", not "1.58e-05–0.0024"); a dash where there is none. A positive value
    too small to show is "<0.001", so that it does not read as zero."""
    number = _number(value)
    if number is None:
        return "—"
    text = f"{number:.{digits}f}"
    if number > 0 and float(text) == 0:
        return f"<{10**-digits:.{digits}f}"
    return text if float(text) != 0 else f"{0:.{digits}f}"  # no "-0.000"


def fmt_signed(value: Any, digits: int = 3) -> str:
    """A difference with its sign and ``digits`` decimals (+0.012, -0.030, +0.001 — not "+0.00082"); a
    dash where there is none."""
    number = _number(value)
    return "—" if number is None else f"{number:+.{digits}f}"


def fmt_pct(value: Any, digits: int = 1) -> str:
    if value is None or isinstance(value, bool):
        return "—"
    try:
        number = float(value) * 100
    except (TypeError, ValueError):
        return "—"
    return f"{number:.{digits}f}%" if math.isfinite(number) else "—"


def fmt_metric(value: Any, key: str) -> str:
    """Ratios as percentages (how the paper prints them), times and lengths as plain numbers."""
    if key in {"space_utilization", "occupancy", "collapsed_placement", "dangerous_operation"}:
        return fmt_pct(value)
    if key in {"decision_time", "local_stability"}:
        return fmt_num(value, 4)
    return fmt_num(value, 3)


@lru_cache(maxsize=1)
def environment() -> jinja2.Environment:
    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(TEMPLATES_DIR),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        auto_reload=False,  # packaged templates: no stat() of every template file on every page
    )
    env.filters["num"] = fmt_num
    env.filters["pct"] = fmt_pct
    env.filters["signed"] = fmt_signed
    env.filters["metric"] = fmt_metric
    env.filters["start_estimate"] = start_estimate_text
    env.globals["SETTING_TITLES"] = SETTING_TITLES
    env.globals["LOOP_TITLES"] = LOOP_TITLES
    env.globals["LOOP_SHORT"] = LOOP_SHORT
    return env

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

WEB_DIR = Path(__file__).resolve().parent
TEMPLATES_DIR = WEB_DIR / "templates"
STATIC_DIR = WEB_DIR / "static"

SETTING_TITLES = {"math": "Math Pack", "physics": "Physics Pack", "execution": "Execution Pack"}
#: How each protocol is labelled wherever a physical setting's figures are shown (docs/web.md).
PROTOCOL_TITLES = {"closed": "closed loop (the benchmark)", "paper": "paper protocol (plan in Math, replay)"}
#: The same, where a table cell has little room (the full title goes in its tooltip).
PROTOCOL_SHORT = {"closed": "closed loop", "paper": "paper protocol"}


def fmt_num(value: Any, digits: int = 3) -> str:
    """A metric value for a table cell; a dash where there is none."""
    if value is None or isinstance(value, bool):
        return "—"
    try:
        number = float(value)
    except (TypeError, ValueError):
        return "—"
    if not math.isfinite(number):
        return "—"
    if number != 0 and abs(number) < 10 ** (-digits):
        return f"{number:.{max(1, digits - 1)}g}"
    return f"{number:.{digits}f}"


def fmt_signed(value: Any, digits: int = 3) -> str:
    """A difference with its sign (+0.012, −0.030); a dash where there is none."""
    text = fmt_num(value, digits)
    return text if text == "—" or text.startswith("-") else "+" + text


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
    env.globals["SETTING_TITLES"] = SETTING_TITLES
    env.globals["PROTOCOL_TITLES"] = PROTOCOL_TITLES
    env.globals["PROTOCOL_SHORT"] = PROTOCOL_SHORT
    return env

"""``umay status``: what every service says about itself, and whether it is still alive."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import zenoh
from rich.console import Group, RenderableType
from rich.table import Table
from rich.text import Text

from common.keys import SERVICES, Keys
from common.messages import ServiceStatus
from common.queries import alive_services
from deploy.arguments import NOTHING_RUNNING_THERE
from deploy.queries import query_status


@dataclass(frozen=True)
class ServiceView:
    name: str
    alive: bool  # liveliness token present
    status: ServiceStatus | None  # None: did not answer

    @property
    def condition(self) -> str:
        if self.status is None:
            return "alive, not answering" if self.alive else "gone"
        if not self.alive:
            return "answers, token lost"
        return self.status.state


def collect(session: zenoh.Session, keys: Keys, timeout_s: float) -> list[ServiceView]:
    statuses = {s.service: s for s in query_status(session, keys, timeout_s)}
    alive = alive_services(session, keys, timeout_s)
    names = sorted(set(SERVICES) | set(statuses) | alive)
    return [ServiceView(n, n in alive, statuses.get(n)) for n in names]


def verdict(views: list[ServiceView], keys: Keys, looked_on: str) -> tuple[int, str]:
    """``umay status``'s exit code and what to say on standard error: 0 and "" when every
    service is alive and answering (degraded included: it answers), else 1 and which are not,
    or that nothing answered at all where it looked (``looked_on``), for scripts and for a
    user who started nothing or looks under another prefix."""
    down = [v for v in views if v.status is None or not v.alive]
    if not down:
        return 0, ""
    if len(down) == len(views):
        return 1, (
            f"no service answers under prefix {keys.prefix!r} on {looked_on}: "
            + NOTHING_RUNNING_THERE
        )
    return 1, "not every service is up: " + ", ".join(f"{v.name} {v.condition}" for v in down)


def as_json(views: list[ServiceView]) -> dict:
    """Every service's status as JSON data; a figure not measured yet (NaN, say the
    manipulability before actuation's first command) is null, as strict JSON has it."""
    return {
        v.name: {
            "alive": v.alive,
            "condition": v.condition,
            "status": _finite(v.status.model_dump()) if v.status else None,
        }
        for v in views
    }


def _finite(data: Any) -> Any:
    """``data`` with every NaN or infinite float replaced by None."""
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if isinstance(data, dict):
        return {k: _finite(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [_finite(v) for v in data]
    return data


def _short_key(key: str, prefix: str) -> str:
    return key.removeprefix(prefix + "/")


def _fmt(value: float | None, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)


def status_display(views: list[ServiceView], keys: Keys) -> RenderableType:
    """What ``umay status`` shows: a table of the services (a row each: liveness, traffic,
    processing time), then each service's own fields as ``name=value`` lines that wrap to the
    terminal, numbers to four significant digits (``--json`` has them whole); not a column of
    the table, which at 80 to 120 columns folds them into a strip."""
    t = Table(title=f"umay status  {keys.prefix}  {time.strftime('%H:%M:%S')}")
    # Names and numbers whole (a service's name folded at 80 columns read "actuatio / n");
    # the key lists take what width is left, folding at their slashes' length.
    for col in ("service", "condition", "pid", "up s"):
        t.add_column(col, no_wrap=True)
    for col in ("in (Hz, age s)", "out (Hz)", "rej"):
        t.add_column(col, overflow="fold")
    t.add_column("p50/p99 ms", overflow="fold", no_wrap=True)
    details: list[RenderableType] = []
    for v in views:
        s = v.status
        if s is None:
            t.add_row(v.name, v.condition, *["-"] * 6)
            continue
        received = "\n".join(
            f"{_short_key(k, keys.prefix)} {st.rate_hz:.1f} ({_fmt(st.age_s, '.2f')})"
            for k, st in s.received.items()
        )
        published = "\n".join(
            f"{_short_key(k, keys.prefix)} {st.rate_hz:.1f}" for k, st in s.published.items()
        )
        rejected = str(s.rejected) + (f"\n{s.last_rejection[:60]}" if s.rejected else "")
        t.add_row(
            v.name,
            v.condition,
            str(s.pid),
            f"{s.uptime_s:.1f}",
            # As plain text: a rejection's reason repeats what a payload said, "[/x]" included.
            Text(received),
            Text(published),
            Text(rejected),
            f"{_fmt(s.processing_ms_p50, '.2f')}/{_fmt(s.processing_ms_p99, '.2f')}",
        )
        fields = dict(s.fields)
        children = fields.pop("children", None) if v.name == "supervisor" else None
        line = Text.assemble((f"{v.name}: ", "bold"))
        if s.degraded_reason:
            line.append(f"{s.degraded_reason}  ", style="yellow")
        line.append("  ".join(f"{k}={field_text(value)}" for k, value in fields.items()))
        if children:
            line.append(("  " if fields else "") + children_text(children))
        details.append(line)
    return Group(t, *details)


def field_text(value: Any) -> str:
    """A status field for people: floats to four significant digits, in lists and maps too."""
    if isinstance(value, float):
        return format(value, ".4g")
    if isinstance(value, list | tuple):
        return "[" + ", ".join(field_text(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {field_text(v)}" for k, v in value.items()) + "}"
    return str(value)


def children_text(children: dict[str, dict[str, Any]]) -> str:
    """The supervisor's children, a clause each: pid, running or not, restarts, and what went
    wrong where something did (its ``--json`` has every field, the log paths too)."""
    clauses = []
    for name, c in children.items():
        words = [f"pid {c.get('pid')}", "running" if c.get("running") else "not running"]
        if c.get("running") and c.get("answered") is False:
            words.append("starting (no status answer yet)")
        words.append(f"restarts {c.get('restarts', 0)}")
        if c.get("policy", "always") != "always":
            words.append(f"restart policy {c['policy']}")
        if c.get("given_up"):
            words.append("given up")
        if c.get("hang_kills"):
            words.append(f"killed hanging {c['hang_kills']}× (last: {c.get('last_hang')})")
        if c.get("last_exit_codes"):
            words.append(f"exit codes {field_text(c['last_exit_codes'])}")
        clauses.append(f"{name} " + ", ".join(words))
    return "; ".join(clauses)

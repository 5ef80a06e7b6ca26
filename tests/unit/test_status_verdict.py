"""``umay status``'s exit code and message (pure: no session), where it says it looked, and
its display."""

from __future__ import annotations

import pytest

from common.keys import SERVICES, Keys
from common.messages import ServiceStatus, TopicStats
from common.session import DEFAULT_ENDPOINT, ENV_CONFIG, ENV_CONNECT, where_connecting
from deploy.launch.status import ServiceView, field_text, status_display, verdict

KEYS = Keys("lab/arm")


def view(name: str, alive: bool = True, answers: bool = True, state: str = "running"):
    status = ServiceStatus(service=name, pid=1, host="h", uptime_s=1.0, state=state)
    return ServiceView(name, alive, status if answers else None)


def test_every_service_up_is_0_even_degraded() -> None:
    views = [view(n, state="degraded" if n == "vision" else "running") for n in SERVICES]
    assert verdict(views, KEYS, DEFAULT_ENDPOINT) == (0, "")


def test_nothing_answering_says_where_it_looked() -> None:
    views = [view(n, alive=False, answers=False) for n in SERVICES]
    code, why = verdict(views, KEYS, "tcp/10.0.0.2:7447")
    assert code == 1
    assert "no service answers under prefix 'lab/arm' on tcp/10.0.0.2:7447" in why
    assert "umay up" in why and "--prefix" in why


def test_some_down_are_named_with_their_condition() -> None:
    views = [view(n) for n in SERVICES if n not in ("sim", "vision")]
    views += [view("sim", alive=False, answers=False), view("vision", answers=False)]
    code, why = verdict(views, KEYS, DEFAULT_ENDPOINT)
    assert code == 1
    assert why == "not every service is up: sim gone, vision alive, not answering"


@pytest.mark.parametrize(
    "connect, env, expected",
    [
        (None, {}, DEFAULT_ENDPOINT),
        (["tcp/a:1", "tcp/b:2"], {}, "tcp/a:1, tcp/b:2"),
        (None, {ENV_CONNECT: "tcp/c:3"}, "tcp/c:3"),
        (None, {ENV_CONFIG: "client.json5"}, "the endpoints of client.json5"),
        (["tcp/a:1"], {ENV_CONFIG: "client.json5"}, "tcp/a:1"),  # ours replace the file's
    ],
)
def test_where_connecting_follows_the_session_precedence(
    monkeypatch: pytest.MonkeyPatch, connect, env: dict, expected: str
) -> None:
    monkeypatch.delenv(ENV_CONNECT, raising=False)
    monkeypatch.delenv(ENV_CONFIG, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    assert where_connecting(connect) == expected


def test_the_display_fits_80_columns_and_rounds_the_fields() -> None:
    """The services' table, then each one's fields as lines that wrap: at 80 columns no line
    is cut, every field is there, numbers to four significant digits."""
    import io

    from rich.console import Console

    views = [view(n) for n in SERVICES]
    traffic = TopicStats(count=300, rate_hz=30.0, age_s=0.01)
    for v in views:  # as the services report theirs: several keys in, several out
        v.status.received = {KEYS.joint_state: traffic, KEYS.rgb: traffic}
        v.status.published = {f"{KEYS.prefix}/{v.name}/joint_command": traffic}
    views[0].status.fields.update(
        manipulability=0.0137295287779395, saturated_joints=[1, 2], gains={"a": 1.23456789}
    )
    views[1].status.degraded_reason = "marker not usable (target: lost, no blob)"
    out = io.StringIO()
    Console(file=out, width=80, color_system=None).print(status_display(views, KEYS))
    text = out.getvalue()
    assert max(len(line) for line in text.splitlines()) <= 80
    rows = [line for line in text.splitlines() if line.startswith("│ ")]
    assert [r.split("│")[1].strip() for r in rows if r.split("│")[1].strip()] == list(SERVICES)
    assert "manipulability=0.01373" in text and "saturated_joints=[1, 2]" in text
    assert "gains={a: 1.235}" in text
    assert f"{views[1].name}: marker not usable (target: lost, no blob)" in text
    assert field_text(2.0) == "2" and field_text(True) == "True" and field_text("") == ""


def test_the_supervisors_children_read_as_a_clause_each() -> None:
    import io

    from rich.console import Console

    sup = view("supervisor")
    child = {
        "pid": 12, "running": True, "answered": True, "restarts": 0, "last_exit_codes": [],
        "policy": "always", "given_up": False, "hang_kills": 0, "last_hang": "",
        "log": "out/logs/sim.log",
    }  # fmt: skip
    gone = {
        **child, "pid": None, "running": False, "restarts": 3, "last_exit_codes": [1, -9],
        "given_up": True,
    }  # fmt: skip
    starting = {**child, "pid": 13, "answered": False}
    sup.status.fields["children"] = {"sim": child, "vision": gone, "controller": starting}
    out = io.StringIO()
    Console(file=out, width=200, color_system=None).print(status_display([sup], KEYS))
    text = out.getvalue()
    assert "supervisor: sim pid 12, running, restarts 0; vision pid None, not running, " in text
    assert "controller pid 13, running, starting (no status answer yet), restarts 0" in text
    assert "restarts 3, given up, exit codes [1, -9]" in text and "sim.log" not in text
    # Its own fields come first, set apart from the children's clauses.
    sup.status.fields = {"cpu_wakeup_latency": "held: 0 µs", **sup.status.fields}
    out = io.StringIO()
    Console(file=out, width=200, color_system=None).print(status_display([sup], KEYS))
    assert "supervisor: cpu_wakeup_latency=held: 0 µs  sim pid 12, running" in out.getvalue()


def test_status_json_is_strict_json_before_a_figure_is_measured() -> None:
    """A figure not measured yet (actuation's manipulability before its first command is NaN)
    is null: `umay status --json | jq` must parse."""
    import json

    from deploy.launch.status import as_json

    v = view("actuation")
    v.status.fields.update(manipulability=float("nan"), margins=[1.0, float("inf")])
    text = json.dumps(as_json([v]), allow_nan=False)  # raises on NaN or inf
    fields = json.loads(text)["actuation"]["status"]["fields"]
    assert fields["manipulability"] is None and fields["margins"] == [1.0, None]


def test_a_rejection_reason_from_a_payload_is_shown_as_it_is() -> None:
    """The last rejection repeats what a payload said; square brackets in it are not markup."""
    import io

    from rich.console import Console

    v = view("vision")
    v.status.rejected, v.status.last_rejection = 1, "segment '[/x]' is not a frame ring's"
    out = io.StringIO()
    Console(file=out, width=200, color_system=None).print(status_display([v], KEYS))
    assert "segment '[/x]' is not a frame ring's" in out.getvalue()

"""What ``umay replay`` reports, and ``--check``: the replayed outputs against the recorded
ones, matched by ``header.frame_seq`` and compared field by field (pure: msgpack payloads in,
the report's counts, largest differences and first examples out). Why the tolerances are what
they are: :mod:`deploy.recording.replay`."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import msgpack
from pydantic import BaseModel

# Wall-clock stamps and counters differ from run to run by nature.
IGNORED_FIELDS = frozenset({"header.seq", "header.send_time_s", "header.recv_time_s"})


class Difference(BaseModel):
    frame_seq: int
    path: str
    recorded: str
    replayed: str


class ReplayReport(BaseModel):
    recording: str
    service: str
    speed: str  # "max" (lockstep) or the factor
    prefix: str
    log_path: str
    inputs_published: int
    frames: int  # trigger inputs published (one expected output each)
    outputs: int  # captured outputs with frame_seq >= 0, repeats included
    no_answer: int  # lockstep frames whose output did not come within the timeout
    skipped_inputs: int  # inputs of frames the service never answered in the recording
    wall_time_s: float
    check: bool
    tolerance: float
    compared: int = 0
    matched: int = 0
    differing: int = 0
    missing: int = 0  # recorded output, none replayed
    extra: int = 0  # replayed output, none recorded
    max_abs_diff: dict[str, float] = {}  # numeric field path → max |recorded - replayed|
    other_diffs: dict[str, int] = {}  # non-numeric field path → frames where it differs
    examples: list[Difference] = []
    notes: list[str] = []
    ok: bool


def flatten(obj: Any, path: str = "") -> Iterator[tuple[str, Any]]:
    """``{"a": [1, {"b": 2}]}`` → ``("a[0]", 1), ("a[1].b", 2)``."""
    if isinstance(obj, dict):
        for k in sorted(obj, key=str):
            yield from flatten(obj[k], f"{path}.{k}" if path else str(k))
    elif isinstance(obj, list | tuple):
        for i, v in enumerate(obj):
            yield from flatten(v, f"{path}[{i}]")
    else:
        yield path, obj


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _short(v: Any) -> str:
    text = repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


def compare_messages(
    recorded: dict[str, Any], replayed: dict[str, Any]
) -> tuple[dict[str, float], dict[str, tuple[str, str]]]:
    """Per numeric field path the absolute difference; per other differing path the two
    values. ``header.seq`` and ``header.send_time_s`` are ignored."""
    a, b = dict(flatten(recorded)), dict(flatten(replayed))
    numeric: dict[str, float] = {}
    other: dict[str, tuple[str, str]] = {}
    for path in sorted(a.keys() | b.keys()):
        if path in IGNORED_FIELDS:
            continue
        if path not in a or path not in b:
            other[path] = (
                _short(a[path]) if path in a else "(absent)",
                _short(b[path]) if path in b else "(absent)",
            )
            continue
        va, vb = a[path], b[path]
        if _is_number(va) and _is_number(vb):
            fa, fb = float(va), float(vb)
            if math.isnan(fa) or math.isnan(fb):
                numeric[path] = 0.0 if math.isnan(fa) and math.isnan(fb) else math.inf
            else:
                numeric[path] = abs(fa - fb)
        elif va != vb or type(va) is not type(vb):
            other[path] = (_short(va), _short(vb))
    return numeric, other


def field_defaults(model: type[BaseModel]) -> dict[str, Any]:
    """The fields of ``model`` that have a default, with it, and those of the models it nests
    (a required ``header`` whose ``run`` a recording predates), as nested dicts."""
    defaults: dict[str, Any] = {}
    for name, info in model.model_fields.items():
        kind = info.annotation
        if not info.is_required():
            defaults[name] = info.get_default(call_default_factory=True)
        elif isinstance(kind, type) and issubclass(kind, BaseModel) and field_defaults(kind):
            defaults[name] = field_defaults(kind)
    return defaults


def with_defaults(defaults: dict[str, Any], data: dict[str, Any]) -> dict[str, Any]:
    """``data`` with what it lacks of ``defaults`` (:func:`field_defaults`), at every depth."""
    out = dict(defaults)
    for key, value in data.items():
        default = defaults.get(key)
        nested = isinstance(default, dict) and isinstance(value, dict)
        out[key] = with_defaults(default, value) if nested else value
    return out


def check_outputs(
    report: ReplayReport,
    recorded: dict[int, bytes],
    replayed: dict[int, bytes],
    defaults: dict[str, Any] | None = None,
) -> None:
    """Fill the comparison fields of ``report``. ``defaults`` (:func:`field_defaults` of the
    output's model): a field the recorded message lacks reads as its default, as the service
    itself would decode it (a recording made before the field existed); one whose default is
    None is an output added since, which the recording cannot say, and is not compared (a
    note names it)."""
    report.missing = len(recorded.keys() - replayed.keys())
    report.extra = len(replayed.keys() - recorded.keys())
    max_diff: dict[str, float] = {}
    other: dict[str, int] = {}
    fill = defaults or {}
    added = {name for name, default in fill.items() if default is None}
    unrecorded: set[str] = set()
    for seq in sorted(recorded.keys() & replayed.keys()):
        raw = msgpack.unpackb(recorded[seq], raw=False)
        was = with_defaults(fill, raw)
        now = msgpack.unpackb(replayed[seq], raw=False)
        for name in added - raw.keys():  # an output added since: the recording cannot say
            was.pop(name)
            if now.pop(name, None) is not None:
                unrecorded.add(name)
        numeric, different = compare_messages(was, now)
        report.compared += 1
        for path, d in numeric.items():
            max_diff[path] = max(max_diff.get(path, 0.0), d)
        over = [(p, d) for p, d in numeric.items() if d > report.tolerance]
        for path in different:
            other[path] = other.get(path, 0) + 1
        if over or different:
            report.differing += 1
            if len(report.examples) < 5:
                path = next(iter(different), None) or max(over, key=lambda x: x[1])[0]
                ra, rb = dict(flatten(was)), dict(flatten(now))
                report.examples.append(
                    Difference(
                        frame_seq=seq,
                        path=path,
                        recorded=_short(ra.get(path, "(absent)")),
                        replayed=_short(rb.get(path, "(absent)")),
                    )
                )
        else:
            report.matched += 1
    report.max_abs_diff = max_diff
    report.other_diffs = other
    if unrecorded:
        report.notes.append(
            f"not compared, the recording predates them: {', '.join(sorted(unrecorded))}"
        )
    report.ok = (
        report.compared > 0
        and report.differing == 0
        and report.missing == 0
        and not report.extra
        and report.no_answer == 0  # a frame the service did not answer is not a match
    )


def format_report(report: ReplayReport, max_fields: int = 20) -> str:
    mode = "lockstep" if report.speed == "max" else f"speed ×{report.speed}"
    lines = [
        f"replay of {report.service} on {report.recording} ({mode}, {report.wall_time_s:.1f} s)",
        f"  inputs published  {report.inputs_published} ({report.frames} frames)",
        f"  outputs           {report.outputs}"
        + (f"  ({report.no_answer} frames unanswered)" if report.no_answer else ""),
        f"  service log       {report.log_path}",
    ]
    lines += [f"  note: {n}" for n in report.notes]
    if not report.check:
        if not report.ok:
            lines.append(f"  result: FAILED ({report.no_answer} frames went unanswered)")
        return "\n".join(lines)
    tol = "bit-identical" if report.tolerance == 0 else f"tolerance {report.tolerance:g}"
    lines += [
        f"  check ({tol}, by frame_seq; header.seq and header.send_time_s ignored)",
        f"    matched {report.matched}  differing {report.differing}  "
        f"missing {report.missing}  extra {report.extra}",
    ]
    over = sorted(
        ((p, d) for p, d in report.max_abs_diff.items() if d > report.tolerance),
        key=lambda x: (-x[1], x[0]),
    )
    if over or report.other_diffs:
        lines.append("  differing fields (max |recorded - replayed| over the frames):")
        width = max(len(p) for p, _ in [*over, *((p, 0) for p in report.other_diffs)])
        for p, d in over[:max_fields]:
            lines.append(f"    {p:<{width}}  {d:.6g}")
        if len(over) > max_fields:
            lines.append(f"    ... and {len(over) - max_fields} more numeric fields")
        for p, n in sorted(report.other_diffs.items()):
            lines.append(f"    {p:<{width}}  differs in {n} frames")
        lines.append("  first differences:")
        for e in report.examples:
            lines.append(f"    frame {e.frame_seq}: {e.path}: {e.recorded} → {e.replayed}")
    elif report.max_abs_diff:
        largest = max(report.max_abs_diff.values())
        lines.append(
            f"    all {len(report.max_abs_diff)} numeric fields within tolerance "
            f"(largest difference {largest:.3g})"
        )
    lines.append("  result: " + ("OK" if report.ok else "FAILED"))
    return "\n".join(lines)

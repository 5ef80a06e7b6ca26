"""``umay domains``'s input checked before anything is drawn, written or started: a bad
``--set`` (the workers were the first to parse it) and the runs ``--resume`` keeps, whose
last line a killed study may have cut off."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from deploy.experiments.compare import CompareError
from deploy.experiments.domains.cli import kept_runs
from deploy.experiments.domains.study import (
    DEFAULT_STUDY,
    DomainRecord,
    RunTask,
    check_overrides,
    judge,
    load_study,
)
from deploy.launch.evaluate import RunResult
from tests.conftest import CliResult

Cli = Callable[..., CliResult]
STUDY, BASE_PATH = load_study(DEFAULT_STUDY)
QUICK = ["domains", "--out", "out", "--cells", "0:1", "--draws", "1", "--modes", "dynamic"]


def record(key: str, detail: str = "") -> DomainRecord:
    result = RunResult(
        scenario=key, mode="dynamic", clock="lockstep", converged=False, reason="timeout",
        frames=90, sim_time_s=12.0, wall_time_s=1.0, final_pixel_rms=3.0,
        final_position_error_m=0.04, final_orientation_error_deg=0.1, path_length_m=0.1,
        min_manipulability=0.01, final_joint_margin_deg=30.0, final_hand_border_px=40.0,
        detail=detail,
    )  # fmt: skip
    return judge(RunTask(key, key, "dynamic", "x.toml", ()), result)


def jsonl(*records: DomainRecord) -> bytes:
    return "".join(r.model_dump_json() + "\n" for r in records).encode()


@pytest.mark.parametrize(
    "item, says",
    [
        ("foo.bar=1", "foo: Extra inputs are not permitted"),
        ("controller.gain=abc", "controller.gain: Input should be a valid number"),
    ],
)
def test_a_bad_set_exits_2_naming_its_field_with_nothing_made(
    item: str, says: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, umay_cli: Cli
) -> None:
    monkeypatch.chdir(tmp_path)
    refused = umay_cli(*QUICK, "--set", item)
    assert refused.returncode == 2, refused.stderr
    assert "umay domains: --set: " in refused.stderr and says in refused.stderr, refused.stderr
    assert list(tmp_path.iterdir()) == []  # no --out folder


def test_the_studys_own_overrides_are_checked_and_named() -> None:
    check_overrides(STUDY, BASE_PATH, ["dynamic", "mpj"], ["controller.gain=0.5"])
    broken = STUDY.model_copy(update={"overrides": ("camera.rgb_hz=-1",)})
    with pytest.raises(CompareError, match=r"(?s)--study overrides: .*camera\.rgb_hz"):
        check_overrides(broken, BASE_PATH, ["dynamic"])


def test_a_cut_last_line_is_dropped_with_a_warning() -> None:
    # A run's detail may hold any character: "°" is two bytes (a cut may split it), U+2028 a
    # line break to str.splitlines but not to JSON.
    a, b, c = record("a", "turned 90°"), record("b", "x\u2028y"), record("c", "turned 90°")
    whole = jsonl(a, b, c)
    assert kept_runs(whole, "runs.jsonl") == ([a, b, c], "")
    assert kept_runs(whole.rstrip(b"\n"), "runs.jsonl") == ([a, b, c], "")
    cut = whole[: whole.rindex("°".encode()) + 1]  # inside the last line's "°"
    runs, warning = kept_runs(cut, "runs.jsonl")
    assert runs == [a, b]
    assert warning.startswith("runs.jsonl line 3: cut off (Invalid JSON")
    assert warning.endswith("that run is done again")
    assert kept_runs(b"", "runs.jsonl") == ([], "")


def test_a_bad_line_before_the_last_is_named() -> None:
    a, b = record("a"), record("b")
    with pytest.raises(ValueError, match=r"--resume: out/runs\.jsonl line 2: not a run"):
        kept_runs(jsonl(a) + b'{"key": "half\n' + jsonl(b), "out/runs.jsonl")
    with pytest.raises(ValueError, match="line 1: not a run"):
        kept_runs(b'{"key": "a"}\n' + jsonl(b), "out/runs.jsonl")  # JSON, not a run


def test_resume_refuses_a_bad_line_before_drawing_anything(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, umay_cli: Cli
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "out").mkdir()
    kept = jsonl(record("a")) + b"garbage\n" + jsonl(record("b"))
    (tmp_path / "out" / "runs.jsonl").write_bytes(kept)
    refused = umay_cli(*QUICK, "--resume")
    assert refused.returncode == 2, refused.stderr
    assert "--resume: out/runs.jsonl line 2: not a run" in refused.stderr, refused.stderr
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["runs.jsonl"]
    assert (tmp_path / "out" / "runs.jsonl").read_bytes() == kept

"""The ``umay`` commands in this process (the ``umay_cli`` fixture), for what they do before
they start anything: bad input exits 2 naming the option or field, with nothing written,
launched or connected (a process start or a Zenoh session fails the test); and ``umay logs``.
The exit code's way out of a real process is tested once, in
``integration/test_integration.py``."""

from __future__ import annotations

import uuid
from collections.abc import Callable
from pathlib import Path

import pytest

from common.keys import Keys
from tests.conftest import CliResult

REFERENCE = Path(__file__).resolve().parents[1] / "data" / "reference.mcap"
Cli = Callable[..., CliResult]


def unique_prefix() -> str:
    return f"test/{uuid.uuid4().hex[:12]}"


@pytest.mark.parametrize(
    "args, fragment",
    [
        (["--mode", "fastest"], "--mode"),
        (["--clock", "sometimes"], "--clock"),
        (["--set", "controller.gain=-1"], "controller.gain"),
        (["--set", "target.position=[2.0, -0.3, 0.0]"], "target.position"),
        (["--set", "robot.q0=[0.0, 0.0]"], "robot.q0"),
        (["--scenario", "/nonexistent.toml"], "no such scenario"),
        (["--result", "/proc/no-such-dir/result.json"], "--result"),
        (["--plot", "/proc/no-such-dir/plots"], "--plot"),
        (["--log-dir", "/proc/no-such-dir/logs"], "--log-dir"),
    ],
)
def test_run_refuses_bad_input_naming_it(
    args: list[str], fragment: str, tmp_path: Path, umay_cli: Cli
) -> None:
    result = tmp_path / "result.json"
    logs = ["--log-dir", str(tmp_path / "logs")]
    run = umay_cli(
        "run", "--quiet", "--prefix", unique_prefix(), "--result", str(result), *logs, *args
    )
    assert run.returncode == 2, run.stderr
    assert fragment in run.stderr
    assert not result.exists()
    assert not (tmp_path / "logs").exists()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--modes", "dynamic", "warp"], "unknown strategy 'warp'"),
        (["--scenarios", "/nonexistent/suite"], "no such directory"),
        (["--jobs", "0"], "--jobs"),
        (["--tolerance", "-1e-4"], "--tolerance"),
        (["--tolerance", "nan"], "--tolerance"),
        (["--set", "controller.gain=-3"], "controller.gain"),
        (["--out", "/proc/no-such-dir/out"], "--out /proc/no-such-dir/out: cannot write"),
    ],
)
def test_compare_refuses_bad_input_naming_it(
    tmp_path: Path, args: list[str], message: str, umay_cli: Cli
) -> None:
    out = tmp_path / "out"
    compare = umay_cli("compare", "--out", str(out), *args)
    assert compare.returncode == 2, compare.stderr
    assert message in compare.stderr
    assert not out.exists()  # nothing written (and umay_cli: nothing launched)


@pytest.mark.parametrize(
    "prefix, reason",
    [("bad*prefix", "no wildcards"), ("a//b", "empty chunk"), ("trail/", "trailing slash")],
)
def test_a_bad_prefix_is_refused_by_name(prefix: str, reason: str, umay_cli: Cli) -> None:
    with pytest.raises(ValueError, match=reason):
        Keys(prefix)
    for command in (["status"], ["service", "vision"]):
        refused = umay_cli(*command, "--prefix", prefix)
        assert refused.returncode == 2, refused.stderr
        assert f"argument --prefix: invalid key prefix {prefix!r}" in refused.stderr
        assert reason in refused.stderr


@pytest.mark.parametrize(
    "args, message",
    [
        (["status", "--connect", "foo"], "argument --connect: invalid endpoint 'foo'"),
        (["record", "x.mcap", "--connect", "tcp/a:1,nope"], "invalid endpoint 'nope'"),
        (["service", "vision", "--connect", "foo"], "argument --connect: invalid endpoint"),
        (["up", "--connect", "foo"], "argument --connect: invalid endpoint 'foo'"),
        (["run", "--listen", "tcp/a:1,tcp/b:2"], "one endpoint, not a list"),
        (["router", "--listen", "7447"], "argument --listen: invalid endpoint '7447'"),
        (["status", "--timeout", "-1"], "argument --timeout: '-1': seconds"),
        (["status", "--timeout", "nan"], "argument --timeout: 'nan': seconds"),
        (["record", "x.mcap", "--duration", "inf"], "argument --duration: 'inf': seconds"),
    ],
)
def test_bad_endpoints_and_durations_are_refused_by_name(
    args: list[str],
    message: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    umay_cli: Cli,
) -> None:
    monkeypatch.chdir(tmp_path)  # where a relative x.mcap would go
    refused = umay_cli(*args)
    assert refused.returncode == 2, refused.stderr
    assert message in refused.stderr
    assert not list(tmp_path.iterdir())  # nothing written (and umay_cli: nothing started)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--frames", "0"], "--frames must be at least 1"),
        (["--seed", "-1"], "--seed 0 or more"),
        (["--scenario", "none.toml"], "none.toml: no such scenario file"),
        (["--set", "camera.width_px=1"], "camera.width_px: Input should be greater"),
        (
            ["--json", "file/inside.json"],
            "--json file/inside.json: file exists and is not a folder",
        ),
    ],
)
def test_accuracy_refuses_bad_input_before_loading_the_simulator(
    args: list[str],
    message: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    umay_cli: Cli,
) -> None:
    import deploy.experiments.accuracy as accuracy

    def no_world(*_args: object) -> None:
        raise AssertionError("the simulator was loaded")

    monkeypatch.setattr(accuracy, "World", no_world)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "file").write_text("x")
    refused = umay_cli("accuracy", *args)
    assert refused.returncode == 2, refused.stderr
    assert message in refused.stderr, refused.stderr


def test_bench_refuses_bad_options_with_exit_2(tmp_path: Path, umay_cli: Cli) -> None:
    for args in (["--size", "640by480"], ["--mode", "fast"], ["--frames", "1"], ["--repeat", "0"]):
        refused = umay_cli("bench", *args, "--log-dir", str(tmp_path))
        assert refused.returncode == 2, (args, refused.stderr)
        assert "umay bench" in refused.stderr


def test_bench_refuses_an_unwritable_output_before_it_starts(tmp_path: Path, umay_cli: Cli) -> None:
    """Found before the runs (minutes with --repeat), not after them with a traceback."""
    (tmp_path / "file").write_text("x")
    for option, path in (("--json", tmp_path / "file" / "b.json"), ("--figure", "b.txt")):
        refused = umay_cli("bench", option, str(path), "--log-dir", str(tmp_path / "logs"))
        assert refused.returncode == 2, refused.stderr
        assert f"umay bench: {option} {path}:" in refused.stderr
        assert not (tmp_path / "logs").exists()  # and umay_cli: no service was started


def test_replay_and_info_refuse_bad_input_with_exit_2(tmp_path: Path, umay_cli: Cli) -> None:
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file")
    cases = [
        (["replay", str(tmp_path / "none.mcap"), "--service", "vision"], "no such file"),
        (["replay", str(REFERENCE), "--service", "sim"], "unknown service"),
        (["replay", str(REFERENCE), "--service", "vision", "--speed", "fast"], "--speed"),
        (["replay", str(REFERENCE), "--service", "vision", "--speed", "inf"], "--speed 'inf'"),
        (["replay", str(junk), "--service", "vision"], "junk.mcap: not an MCAP recording"),
        (["replay", str(REFERENCE), "--service", "controller", "--set", "controller.gain=-1"],
         "controller.gain"),
        (["info", str(tmp_path / "none.mcap")], "no such file"),
        (["info", str(junk)], "junk.mcap: not an MCAP recording"),
        (["replay", str(REFERENCE), "--service", "vision", "--log-dir", "/proc/no/logs"],
         "umay replay: --log-dir /proc/no/logs: cannot write"),
    ]  # fmt: skip
    for args, fragment in cases:
        if args[0] == "replay" and "--log-dir" not in args:
            args = [*args, "--log-dir", str(tmp_path / "logs")]
        refused = umay_cli(*args)
        assert refused.returncode == 2, (args, refused.stdout, refused.stderr)
        assert fragment in refused.stderr, (args, refused.stderr)
    assert not (tmp_path / "logs").exists()  # nothing written (umay_cli: nothing launched)


def test_umay_plot_refuses_a_file_that_is_not_mcap(tmp_path: Path, umay_cli: Cli) -> None:
    not_mcap = tmp_path / "hostname"
    not_mcap.write_text("box\n")
    refused = umay_cli("plot", str(not_mcap), "--out", str(tmp_path / "plots"))
    assert refused.returncode == 2, refused.stderr
    assert f"umay plot: {not_mcap}: not an MCAP recording" in refused.stderr


def test_plot_and_record_refuse_bad_output_or_keys_naming_them(
    tmp_path: Path, umay_cli: Cli
) -> None:
    (tmp_path / "file").write_text("x")
    blocked = tmp_path / "file" / "inside"  # under a file: no folder can be made there
    cases = [
        (("plot", str(REFERENCE), "--out", str(blocked)), f"umay plot: --out {blocked}:"),
        (("record", str(blocked / "r.mcap"), "--duration", "1"), "umay record: OUT.mcap"),
        (("record", str(tmp_path / "k.mcap"), "--keys", "a//b"), "umay record: --keys 'a//b': "),
    ]
    for args, message in cases:
        refused = umay_cli(*args)
        assert refused.returncode == 2, refused.stderr
        assert message in refused.stderr
    assert not (tmp_path / "k.mcap").exists()


def test_export_refuses_bad_input(tmp_path: Path, umay_cli: Cli) -> None:
    not_mcap = tmp_path / "notes.mcap"
    not_mcap.write_text("not a recording")
    for argv, says in (
        ([str(tmp_path / "missing.mcap"), "--foxglove", str(tmp_path / "o.mcap")], "no such file"),
        ([str(not_mcap), "--foxglove", str(tmp_path / "o.mcap")], "not an MCAP recording"),
        ([str(not_mcap)], "--foxglove OUT.mcap"),
    ):
        refused = umay_cli("export", *argv)
        assert refused.returncode == 2, refused.stderr
        assert says in refused.stderr
    assert not (tmp_path / "o.mcap").exists()


def test_umay_logs_shows_the_last_lines_of_a_service_log(tmp_path: Path, umay_cli: Cli) -> None:
    (tmp_path / "sim.log").write_text("".join(f"line {i}\n" for i in range(10)))

    def logs(*args: str) -> CliResult:
        return umay_cli("logs", "sim", "--log-dir", str(tmp_path), *args)

    assert logs("-n", "3").stdout.splitlines() == ["line 7", "line 8", "line 9"]
    none = logs("-n", "0")
    assert none.returncode == 0 and none.stdout == ""
    negative = logs("-n", "-5")
    assert negative.returncode == 2 and "-n -5" in negative.stderr and negative.stdout == ""

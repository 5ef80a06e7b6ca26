"""The ``umay`` commands in this process (the ``umay_cli`` fixture), for what they do before
they start anything: bad input exits 2 naming the option or field, with nothing written,
launched or connected (a process start or a Zenoh session fails the test); and ``umay logs``.
The exit code's way out of a real process is tested once, in
``integration/test_integration.py``; ``umay campaign``'s refusals in ``test_campaign.py``."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
from mcap.writer import MCAP0_MAGIC

from tests.conftest import CliResult

REFERENCE = str(Path(__file__).resolve().parents[1] / "data" / "reference.mcap")
Cli = Callable[..., CliResult]
# Run in a folder holding only these: a plain file (no folder can be made under it) and a
# file named like a recording that is not one. Outputs are named relative to the folder, so
# that anything a command wrote would show up there.
FILE, JUNK, CUT = "file", "junk.mcap", "cut.mcap"  # CUT: an MCAP file cut after its magic
LINK = "link.mcap"  # a hard link to JUNK: the same file by another name
RUN = ["run", "--quiet", "--prefix", "test/cli", "--result", "result.json", "--log-dir", "logs"]
REPLAY = ["replay", REFERENCE, "--service", "vision", "--log-dir", "logs"]


def case(*argv: str, says: str) -> object:
    """A refused command line; its test id is the line, shorter (no common options)."""
    shown = list(argv)
    for common in (RUN, REPLAY):
        if shown[: len(common)] == common:
            shown = [common[0], *shown[len(common) :]]
    words = ["reference.mcap" if w == REFERENCE else w for w in shown]
    return pytest.param(list(argv), says, id=" ".join(words))


REFUSED = [
    case(*RUN, "--mode", "fastest", says="--mode"),
    case(*RUN, "--clock", "sometimes", says="--clock"),
    case(*RUN, "--set", "controller.gain=-1", says="controller.gain"),
    case(*RUN, "--set", "target.position=[2.0, -0.3, 0.0]", says="target.position"),
    case(*RUN, "--set", "robot.q0=[0.0, 0.0]", says="robot.q0"),
    case(*RUN, "--scenario", "/nonexistent.toml", says="no such scenario"),
    case(*RUN, "--scenario", ".", says=".: cannot read it: Is a directory"),
    case(*RUN, "--scenario", CUT, says="cut.mcap: not a text file (not UTF-8 at byte 0)"),
    case(*RUN, "--result", "/proc/no-such-dir/result.json", says="--result"),
    case(*RUN, "--plot", "/proc/no-such-dir/plots", says="--plot"),
    case(*RUN, "--log-dir", "/proc/no-such-dir/logs", says="--log-dir"),
    # The folders the checks before it made (--plot's, --result's) removed again.
    case(*RUN, "--plot", "p/q", "--result", "r/s.json", "--log-dir", FILE, says="--log-dir file"),
    case("run", "--listen", "tcp/a:1,tcp/b:2", says="one endpoint, not a list"),
    case(*RUN, "--timeout", "-5", says="argument --timeout: '-5': seconds, a finite number"),
    case("up", "--scenario", "nope.toml", says="umay up: nope.toml: no such scenario file"),
    case("up", "--set", "controller.gain=-1", "--log-dir", "logs", says="controller.gain"),
    case("up", "--scenario", ".", "--log-dir", "logs", says="umay up: .: cannot read it"),
    case("up", "--view", "--view-port", "70000", says="--view-port: '70000': a TCP port, 0-65535"),
    case("service", "nosuch", says="invalid choice: 'nosuch'"),
    case("router", "--config", "nope.json5", says="nope.json5: No such file or directory"),
    case("view", "--port", "99999", says="--port 99999: 0-65535"),
    case("domains", "--out", "out", "--jobs", "0", says="--jobs: must be at least 1, not 0"),
    case("domains", "--out", "out", "--jobs", "2", "--cluster", "local:1", says="not allowed with"),
    case("domains", "--out", "out", "--draws", "0", says="--draws: '0': a whole number, at least"),
    case("domains", "--out", "out", "--cells", "5:2", says="--cells: '5:2': A below B"),
    case("domains", "--out", "out", "--cluster", "bogus", says="--cluster bogus: a scheduler's"),
    case("domains", "--out", "out", "--cluster", "local:x", says="--cluster local:x: local:N"),
    case("domains", "--out", "out", "--cluster", "local:0", says="at least one worker"),
    case("domains", "--out", "/proc/x/y", says="--out /proc/x/y: cannot write"),
    case("compare", "--out", "out", "--modes", "dynamic", "warp", says="unknown strategy 'warp'"),
    case("compare", "--out", "out", "--scenarios", "/nonexistent/suite", says="no such directory"),
    case("compare", "--out", "out", "--jobs", "0", says="--jobs"),
    case("compare", "--out", "out", "--tolerance", "-1e-4", says="--tolerance"),
    case("compare", "--out", "out", "--tolerance", "nan", says="--tolerance"),
    case("compare", "--out", "out", "--set", "controller.gain=-3", says="controller.gain"),
    case("compare", "--out", "/proc/no-such-dir/out", says="--out /proc/no-such-dir/out: cannot"),
    case("status", "--prefix", "bad*prefix", says="--prefix: invalid key prefix 'bad*prefix': no"),
    case("status", "--prefix", "a//b", says="--prefix: invalid key prefix 'a//b': empty, or"),
    case("service", "vision", "--prefix", "trail/", says="invalid key prefix 'trail/': empty"),
    case("service", "vision", "--prefix", "a*", says="argument --prefix: invalid key prefix 'a*'"),
    case("status", "--connect", "foo", says="argument --connect: invalid endpoint 'foo'"),
    case("status", "--timeout", "-1", says="argument --timeout: '-1': seconds"),
    case("status", "--timeout", "nan", says="argument --timeout: 'nan': seconds"),
    case("service", "vision", "--connect", "foo", says="argument --connect: invalid endpoint"),
    case("up", "--connect", "foo", says="argument --connect: invalid endpoint 'foo'"),
    case("status", "--connect", "tcp/127.0.0.1:99999", says="port '99999' is not 0-65535"),
    case("record", "p.mcap", "--connect", "tcp/h:1,tcp/h", says="'tcp/h': no :port after"),
    case("run", "--listen", "tcp/127.0.0.1:70000", says="--listen: invalid endpoint 'tcp/127."),
    case("router", "--listen", "7447", says="argument --listen: invalid endpoint '7447'"),
    case("record", "x.mcap", "--connect", "tcp/a:1,nope", says="invalid endpoint 'nope'"),
    case("record", "x.mcap", "--duration", "inf", says="argument --duration: 'inf': seconds"),
    case("record", f"{FILE}/r.mcap", "--duration", "1", says="umay record: OUT.mcap"),
    case("record", "k.mcap", "--keys", "a//b", says="umay record: --keys 'a//b': "),
    case("record", "k.mcap", "--scenario", CUT, says="umay record: cut.mcap: not a text file"),
    case("record", "k.mcap", "--set", "controller.gain=-1", says="controller.gain: Input"),
    case("record", "d/k.mcap", "--set", "foo.bar=1", says="foo: Extra inputs are not permitted"),
    case("accuracy", "--frames", "0", says="--frames: '0': a whole number, at least 1"),
    case("accuracy", "--seed", "-1", says="--seed: '-1': a seed, a whole number 0 or more"),
    case("campaign", "--out", "out", "--seed", "-3", says="--seed: '-3': a seed, a whole"),
    case("domains", "--out", "out", "--seed", "-2", says="--seed: '-2': a seed, a whole"),
    case("accuracy", "--scenario", "none.toml", says="none.toml: no such scenario file"),
    case("accuracy", "--set", "camera.width_px=1", says="camera.width_px: Input should be greater"),
    case("accuracy", "--set", "target.position=[0.9, -0.1, 0.5]", says="umay accuracy: target"),
    case("accuracy", "--json", f"{FILE}/in.json", says=f"--json {FILE}/in.json: file exists"),
    case("bench", "--size", "640by480", "--log-dir", "logs", says="umay bench"),
    case("bench", "--mode", "fast", "--log-dir", "logs", says="umay bench"),
    case("bench", "--frames", "1", "--log-dir", "logs", says="umay bench"),
    case("bench", "--repeat", "0", "--log-dir", "logs", says="umay bench"),
    case("bench", "--json", f"{FILE}/b.json", "--log-dir", "logs", says=f"--json {FILE}/b.json:"),
    case("bench", "--figure", "b.txt", "--log-dir", "logs", says="umay bench: --figure b.txt:"),
    case("bench", "--workflows", "--set", "a.b=1", "--log-dir", "logs", says="fresh clones; --set"),
    case("bench", "--workflows", "--json", f"{FILE}/w.json", says=f"--json {FILE}/w.json:"),
    case("replay", "none.mcap", "--service", "vision", says="no such file"),
    case("replay", REFERENCE, "--service", "sim", says="unknown service"),
    case(*REPLAY, "--speed", "fast", says="--speed"),
    case(*REPLAY, "--speed", "inf", says="--speed 'inf'"),
    case("replay", JUNK, "--service", "vision", says="junk.mcap: not an MCAP recording"),
    case(*REPLAY, "--set", "controller.gain=-1", says="controller.gain"),
    case(*REPLAY, "--log-dir", "/proc/no/logs", says="replay: --log-dir /proc/no/logs: cannot"),
    case("info", "none.mcap", says="no such file"),
    case("info", JUNK, says="junk.mcap: not an MCAP recording"),
    case("info", CUT, says="cut.mcap: an MCAP file cut short before its header ended"),
    case("info", ".", says=".: a folder, not a recording"),
    case("plot", CUT, "--out", "plots", says="umay plot: cut.mcap: an MCAP file cut short"),
    case("export", CUT, "--foxglove", "o.mcap", says="umay export: cut.mcap: an MCAP file cut"),
    case("plot", JUNK, "--out", "plots", says="umay plot: junk.mcap: not an MCAP recording"),
    case("plot", REFERENCE, "--out", f"{FILE}/in", says=f"umay plot: --out {FILE}/in:"),
    case("export", "none.mcap", "--foxglove", "o.mcap", says="no such file"),
    case("export", JUNK, "--foxglove", "o.mcap", says="not an MCAP recording"),
    case("export", JUNK, says="--foxglove OUT.mcap"),
    case("export", JUNK, "--foxglove", LINK, says="--foxglove must not overwrite the recording"),
]


@pytest.mark.parametrize("argv, says", REFUSED)
def test_bad_input_exits_2_naming_it_and_writes_nothing(
    argv: list[str], says: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, umay_cli: Cli
) -> None:
    import deploy.experiments.accuracy as accuracy

    def no_simulator(*_args: object) -> None:
        raise AssertionError("the simulator was loaded")

    monkeypatch.setattr(accuracy, "World", no_simulator)  # umay accuracy: checks before
    monkeypatch.chdir(tmp_path)
    (tmp_path / FILE).write_text("x")
    (tmp_path / JUNK).write_bytes(b"not an mcap file")
    (tmp_path / CUT).write_bytes(MCAP0_MAGIC)
    (tmp_path / LINK).hardlink_to(tmp_path / JUNK)
    refused = umay_cli(*argv)
    assert refused.returncode == 2, refused.stderr
    assert says in refused.stderr, refused.stderr
    assert ".rs:" not in refused.stderr  # no Rust source location from a Zenoh error
    assert sorted(p.name for p in tmp_path.iterdir()) == [CUT, FILE, JUNK, LINK]  # as they were
    assert (tmp_path / LINK).read_bytes() == b"not an mcap file"


def test_umay_logs_shows_the_last_lines_of_a_service_log(tmp_path: Path, umay_cli: Cli) -> None:
    (tmp_path / "sim.log").write_text("".join(f"line {i}\n" for i in range(10)))

    def logs(*args: str) -> CliResult:
        return umay_cli("logs", "sim", "--log-dir", str(tmp_path), *args)

    assert logs("-n", "3").stdout.splitlines() == ["line 7", "line 8", "line 9"]
    none = logs("-n", "0")
    assert none.returncode == 0 and none.stdout == ""
    negative = logs("-n", "-5")
    assert negative.returncode == 2 and "-n -5" in negative.stderr and negative.stdout == ""


def test_run_refuses_a_plot_folder_whose_recording_would_be_a_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, umay_cli: Cli
) -> None:
    """``--plot DIR`` records the run to DIR/run.mcap to plot it: a folder there is named
    before anything starts."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "plots" / "run.mcap").mkdir(parents=True)
    refused = umay_cli(*RUN, "--plot", "plots")
    assert refused.returncode == 2, refused.stderr
    assert "--plot plots/run.mcap: is a folder, expected a file" in refused.stderr

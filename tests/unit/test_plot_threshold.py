"""``umay plot`` draws the recorded run's convergence threshold, as ``umay run --plot`` does,
not the default one."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
from matplotlib.figure import Figure

from common.config import load_scenario
from deploy.recording import plots
from deploy.recording.read import RecordingReader
from deploy.recording.record import run_metadata
from tests.conftest import CliResult
from tests.unit.test_plots import PREFIX, write_recording

RECORDED_PX = 0.5  # not the default scenario's 0.25


def recorded(tmp_path: Path, overrides: list[str] | None) -> Path:
    """A recording whose metadata holds the scenario run with ``overrides`` (None: no
    scenario, as ``umay record`` without --scenario writes)."""
    meta = {"prefix": PREFIX} if overrides is None else run_metadata(None, overrides, PREFIX)
    return write_recording(tmp_path / "run.mcap", metadata=meta)


def test_the_threshold_is_the_recorded_scenario_s(tmp_path: Path) -> None:
    rec = recorded(tmp_path, [f"controller.converged_px={RECORDED_PX}"])
    assert plots.recorded_converged_px(RecordingReader(rec)) == (RECORDED_PX, [])


def test_without_a_recorded_scenario_the_default_one_s_with_a_note(tmp_path: Path) -> None:
    px, notes = plots.recorded_converged_px(RecordingReader(recorded(tmp_path, None)))
    assert px == load_scenario().controller.converged_px
    assert notes == ["the recording holds no scenario: the default one was used"]


def test_a_recorded_scenario_that_does_not_load_gives_the_default_with_a_note(
    tmp_path: Path,
) -> None:
    meta = run_metadata(None, [], PREFIX) | {"scenario_toml": "[controller]\nconverged_px = -1\n"}
    rec = write_recording(tmp_path / "run.mcap", metadata=meta)
    px, notes = plots.recorded_converged_px(RecordingReader(rec))
    assert px == load_scenario().controller.converged_px
    assert len(notes) == 1 and "does not load" in notes[0] and "converged_px" in notes[0]


def threshold_lines(fig: Figure) -> list[float]:
    return [
        float(line.get_ydata()[0])  # type: ignore[index]
        for ax in fig.axes
        for line in ax.get_lines()
        if str(line.get_label()).startswith("convergence threshold")
    ]


@pytest.mark.parametrize(
    ("overrides", "drawn_px", "note"),
    [
        ([f"controller.converged_px={RECORDED_PX}"], RECORDED_PX, False),
        (None, load_scenario().controller.converged_px, True),
    ],
)
def test_umay_plot_draws_the_recorded_threshold(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    umay_cli: Callable[..., CliResult],
    overrides: list[str] | None,
    drawn_px: float,
    note: bool,
) -> None:
    rec = recorded(tmp_path, overrides)
    drawn: list[Figure] = []
    draw = plots.feature_error_figure

    def kept(*args: object, **kwargs: object) -> Figure | None:
        fig = draw(*args, **kwargs)  # type: ignore[arg-type]
        if fig is not None:
            drawn.append(fig)
        return fig

    # The figure `umay plot` draws, kept to read its threshold line back (not its pixels).
    monkeypatch.setattr(plots, "feature_error_figure", kept)
    result = umay_cli("plot", str(rec), "--out", str(tmp_path / "figs"))
    assert result.returncode == 0, result.stderr
    assert [threshold_lines(fig) for fig in drawn] == [[drawn_px]]
    assert ("note: the recording holds no scenario" in result.stderr) == note

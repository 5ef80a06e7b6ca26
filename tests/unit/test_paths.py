"""Output paths are checked before a command starts its work (deploy/paths.py)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from deploy.paths import FIGURE_SUFFIXES, OutputPathError, check_output_dir, check_output_file


def test_a_new_file_in_new_folders_is_accepted_and_its_folders_made(tmp_path: Path) -> None:
    target = tmp_path / "a" / "b" / "bench.json"
    assert check_output_file("--json", target) == target
    assert target.parent.is_dir() and not target.exists()  # the folder, not the file
    assert list(target.parent.iterdir()) == []  # the probe left nothing behind


def test_an_existing_file_is_accepted_and_left_as_it_was(tmp_path: Path) -> None:
    target = tmp_path / "old.json"
    target.write_text("{}")
    check_output_file("--json", target)
    assert target.read_text() == "{}"


@pytest.mark.parametrize(
    ("make", "fragment"),
    [
        (lambda tmp: tmp, "is a folder"),  # a folder where a file is wanted
        (lambda tmp: tmp / "file.txt" / "out.json", "not a folder"),  # a file where a folder is
        (lambda tmp: Path("/proc/no-such-dir/out.json"), "cannot write"),  # not even for root
    ],
)
def test_an_unwritable_file_is_refused_naming_the_option(
    tmp_path: Path, make, fragment: str
) -> None:
    (tmp_path / "file.txt").write_text("x")
    target = make(tmp_path)
    with pytest.raises(OutputPathError, match=rf"^--json {re.escape(str(target))}: .*{fragment}"):
        check_output_file("--json", target)


def test_a_figure_must_have_a_format_matplotlib_writes(tmp_path: Path) -> None:
    for suffix in FIGURE_SUFFIXES:
        check_output_file("--figure", tmp_path / f"stages{suffix}", FIGURE_SUFFIXES)
    expected = r"--figure .*expected a \.png or \.svg or \.pdf file"
    with pytest.raises(OutputPathError, match=expected):
        check_output_file("--figure", tmp_path / "stages.json", FIGURE_SUFFIXES)


def test_an_output_folder_may_not_be_a_file(tmp_path: Path) -> None:
    assert check_output_dir("--out", tmp_path / "new").is_dir()
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputPathError, match=r"--out .*not a folder"):
        check_output_dir("--out", tmp_path / "file")

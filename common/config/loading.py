"""Reading a scenario: a TOML file, overrides merged in, validated; every failure a
:class:`ScenarioError` naming the file, the field and the reason."""

from __future__ import annotations

import tomllib
from pathlib import Path

from pydantic import ValidationError

from common.config.scenario import Scenario

DEFAULT_SCENARIO = (
    Path(__file__).resolve().parent.parent.parent / "deploy" / "scenarios" / "default.toml"
)


class ScenarioError(ValueError):
    """A scenario file that cannot be used; the message names the file, field and reason."""


def format_validation_error(err: ValidationError, source: str) -> str:
    lines = [f"{source}: invalid scenario"]
    for e in err.errors():
        loc = ".".join(str(p) for p in e["loc"]) or "(root)"
        lines.append(f"  {loc}: {e['msg']}")
    return "\n".join(lines)


def merge_overrides(data: dict, overrides: dict) -> dict:
    """``overrides`` merged into ``data`` in place, table by table (nested tables too); a value
    that is not a table replaces what was there."""
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(data.get(key), dict):
            merge_overrides(data[key], value)
        else:
            data[key] = value
    return data


def load_scenario(path: str | Path | None = None, overrides: dict | None = None) -> Scenario:
    """Read and validate a scenario TOML file; ``overrides`` (nested tables, as from
    :func:`common.runtime.parse_overrides`) are merged into it first."""
    p = Path(path) if path is not None else DEFAULT_SCENARIO
    try:
        data = tomllib.loads(p.read_text())
    except FileNotFoundError as exc:
        raise ScenarioError(f"{p}: no such scenario file") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{p}: not valid TOML: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{p}: not a text file (not UTF-8 at byte {exc.start})") from exc
    except OSError as exc:  # a directory, no permission, ...
        raise ScenarioError(f"{p}: cannot read it: {exc.strerror or exc}") from exc
    merge_overrides(data, overrides or {})
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(format_validation_error(exc, str(p))) from exc

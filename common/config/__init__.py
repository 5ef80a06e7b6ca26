"""Scenario configuration: one TOML file, validated by pydantic, read by every service.

Each service takes its own table (``[camera]``, ``[vision]``, ``[controller]``, ...) from the
same scenario file, so one file describes one experiment. Every model forbids unknown fields,
so a typo is reported with its path instead of being silently ignored.

One module per table (:mod:`~common.config.camera`, :mod:`~common.config.vision`,
:mod:`~common.config.controller`, :mod:`~common.config.actuation`, :mod:`~common.config.sim`,
:mod:`~common.config.supervisor`, :mod:`~common.config.events`), the scenario that holds them
and its checks across tables (:mod:`~common.config.scenario`), and reading a file
(:mod:`~common.config.loading`). Users import from ``common.config``.
"""

from common.config.actuation import ActuationConfig
from common.config.camera import CalibrationError, CameraConfig, KinectConfig
from common.config.controller import (
    ClearanceCorrection,
    ConstantDepth,
    ControllerConfig,
    JacobianMode,
)
from common.config.events import MAX_TARGET_SPEED_M_S, Event, EventAction
from common.config.loading import (
    DEFAULT_SCENARIO,
    ScenarioError,
    format_validation_error,
    load_scenario,
    merge_overrides,
)
from common.config.scenario import (
    ClockMode,
    MarkerConfig,
    RobotConfig,
    RunConfig,
    Scenario,
    TargetConfig,
    substeps_per_frame,
)
from common.config.sim import SimConfig
from common.config.supervisor import RestartPolicy, SupervisorConfig
from common.config.vision import HsvRange, VisionConfig

__all__ = [
    "DEFAULT_SCENARIO",
    "MAX_TARGET_SPEED_M_S",
    "ActuationConfig",
    "CalibrationError",
    "CameraConfig",
    "ClearanceCorrection",
    "ClockMode",
    "ConstantDepth",
    "ControllerConfig",
    "Event",
    "EventAction",
    "HsvRange",
    "JacobianMode",
    "KinectConfig",
    "MarkerConfig",
    "RestartPolicy",
    "RobotConfig",
    "RunConfig",
    "Scenario",
    "ScenarioError",
    "SimConfig",
    "SupervisorConfig",
    "TargetConfig",
    "VisionConfig",
    "format_validation_error",
    "load_scenario",
    "merge_overrides",
    "substeps_per_frame",
]

"""Every generated block by name: what renders it and what it comes from."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from deploy.docs.bench_alternation_tables import bench_alternations
from deploy.docs.bench_hosts import bench_hosts
from deploy.docs.bench_tables import (
    bench_commands,
    bench_distribution,
    bench_dropped,
    bench_headline,
    bench_kinect,
    bench_latency,
    bench_render,
    bench_runs,
    bench_services,
    bench_stages,
    bench_startup,
    bench_workflows,
)
from deploy.docs.bench_view_tables import bench_view
from deploy.docs.calibration_tables import campaign_calibration
from deploy.docs.campaign_tables import (
    campaign_contacts,
    campaign_goals,
    campaign_stability,
    campaign_summary,
    campaign_taxonomy,
)
from deploy.docs.domains_tables import (
    domains_bands,
    domains_executors,
    domains_summary,
    domains_verdict,
)
from deploy.docs.results_tables import (
    results_compact,
    results_strategies,
    results_verdict,
    suite_camera,
)
from deploy.docs.scenario_tables import scenario_fields
from deploy.docs.sources import (
    ACCURACY_JSON,
    ALTERNATIONS_DIR,
    BENCH_DIR,
    CALIBRATION_DIR,
    CAMPAIGN_DIR,
    CAMPAIGN_JSON,
    CAMPAIGN_RESULTS_JSON,
    CAMPAIGN_STARTS_JSON,
    DOMAINS_JSON,
    EXECUTORS_DIR,
    HOSTS_DIR,
    LOCKSTEP_RUN,
    RESULTS_JSON,
    STARTUP_DIR,
    SUITE_CAMERA_DIR,
    VIEW_DIR,
    WORKFLOWS_DIR,
    Inputs,
)
from deploy.docs.status_tables import status_fields
from deploy.docs.vision_tables import vision_accuracy

CAMPAIGN_SOURCES = f"{CAMPAIGN_JSON}, {CAMPAIGN_DIR}/<variant>/causes.json"


@dataclass(frozen=True)
class Block:
    render: Callable[[Inputs, str], str]
    sources: str  # what it is generated from, for messages


BLOCKS: dict[str, Block] = {
    "results-compact": Block(results_compact, RESULTS_JSON),
    "results-strategies": Block(results_strategies, RESULTS_JSON),
    "results-verdict": Block(results_verdict, RESULTS_JSON),
    "suite-camera": Block(suite_camera, f"{SUITE_CAMERA_DIR}/*/results.json"),
    "bench-headline": Block(bench_headline, f"{BENCH_DIR}/*.json, {WORKFLOWS_DIR}/*.json"),
    "bench-runs": Block(bench_runs, f"{BENCH_DIR}/*.json"),
    "bench-commands": Block(bench_commands, f"{BENCH_DIR}/*.json"),
    "bench-render": Block(bench_render, f"{BENCH_DIR}/*.json"),
    "bench-kinect": Block(bench_kinect, f"{BENCH_DIR}/*.json"),
    "bench-latency": Block(bench_latency, f"{BENCH_DIR}/*.json"),
    "bench-distribution": Block(bench_distribution, f"{BENCH_DIR}/*.json"),
    "bench-stages": Block(bench_stages, f"{BENCH_DIR}/{LOCKSTEP_RUN}.json"),
    "bench-services": Block(bench_services, f"{BENCH_DIR}/*.json"),
    "bench-dropped": Block(bench_dropped, f"{BENCH_DIR}/*.json"),
    "bench-alternations": Block(bench_alternations, f"{ALTERNATIONS_DIR}/*.json"),
    "bench-startup": Block(bench_startup, f"{STARTUP_DIR}/*.json"),
    "bench-workflows": Block(bench_workflows, f"{WORKFLOWS_DIR}/*.json"),
    "bench-hosts": Block(bench_hosts, f"{BENCH_DIR}/{LOCKSTEP_RUN}.json, {HOSTS_DIR}/*.json"),
    "bench-view": Block(bench_view, f"{VIEW_DIR}/*.json"),
    "campaign-summary": Block(campaign_summary, CAMPAIGN_SOURCES),
    "campaign-taxonomy": Block(campaign_taxonomy, CAMPAIGN_SOURCES),
    "campaign-contacts": Block(campaign_contacts, CAMPAIGN_RESULTS_JSON),
    "campaign-stability": Block(campaign_stability, f"{CAMPAIGN_STARTS_JSON}, {CAMPAIGN_SOURCES}"),
    "campaign-goals": Block(campaign_goals, f"{CAMPAIGN_SOURCES}, {RESULTS_JSON}"),
    "campaign-calibration": Block(campaign_calibration, f"{CALIBRATION_DIR}/*/results.json"),
    "vision-accuracy": Block(vision_accuracy, ACCURACY_JSON),
    "scenario-fields": Block(scenario_fields, "common/config/*.py"),
    "status-fields": Block(status_fields, "services/*/status.py, the supervisor's and the view's"),
    "domains-summary": Block(domains_summary, DOMAINS_JSON),
    "domains-bands": Block(domains_bands, DOMAINS_JSON),
    "domains-verdict": Block(domains_verdict, DOMAINS_JSON),
    "domains-executors": Block(domains_executors, f"{EXECUTORS_DIR}/*/domains.json"),
}

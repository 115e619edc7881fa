"""What a sweep's steps will take before they start: the bytes they write and the seconds they run
one after another, from sizes and unit costs measured on the project's machine kind."""

from __future__ import annotations

from crank.estimate import Span, run_time
from crank.sweep_spec import Node

DATASET_BYTES_PER_SAMPLE = 143
"""dataset.mcap per 500 Hz sample (measured: 6.43 MB for 90 s)."""
CAMPAIGN_BYTES_PER_RUN_SAMPLE = 340
"""replay.mcap per replayed run and sample (measured: 20.4 MB for 2 x 2 x 100 runs of 150; 9.04
MB of it the dataset channels, the rest Foxglove's mechanism, scene and plan)."""
FIGURES_BYTES = {"data": 0.7e6, "model": 0.9e6, "solve": 0.4e6, "leaf": 1.8e6}
"""Figures, the Rerun recording and small files of a step (measured on a paper run)."""


def disk_estimate(nodes: list[Node]) -> float:
    """Bytes the steps of `nodes` will write, from the measured sizes above."""
    total = 0.0
    for node in nodes:
        c = node.config
        total += FIGURES_BYTES[node.kind]
        if node.kind == "data":
            total += DATASET_BYTES_PER_SAMPLE * c.generation.n_samples
        elif node.kind == "leaf":
            runs = c.replay.runs * 2 * len(c.replay.modes)
            total += CAMPAIGN_BYTES_PER_RUN_SAMPLE * runs * c.ocp.horizon
    return total


def time_estimate(nodes: list[Node]) -> Span:
    """Seconds the steps of `nodes` take one after another on an idle machine (crank.estimate:
    a data step is a run's generate stage, a model step its train stage, and so on)."""
    stage_of = {
        "data": ("generate",),
        "model": ("train",),
        "solve": ("solve", "plan", "train_plan", "solve_plan"),
    }
    total = Span(0.0, 0.0)
    for node in nodes:
        times = run_time(node.config)
        for stage in stage_of.get(node.kind, ("replay", "heldout")):
            total = total + times.get(stage, Span(0.0, 0.0))
    return total

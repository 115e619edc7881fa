"""Replay campaigns of OCP torques on the twin: simulation, statistics, logs, recordings."""

"""Tests of ``mission.telemetry``."""

"""Tests of ``mission.flight``."""

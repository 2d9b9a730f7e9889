"""Tests of ``mission.safety``."""

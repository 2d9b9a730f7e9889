"""Tests of ``mission.sim``."""

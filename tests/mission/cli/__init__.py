"""Tests of ``mission.cli``."""

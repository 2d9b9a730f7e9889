"""Tests of ``mission.vehicle``."""

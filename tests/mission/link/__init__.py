"""Tests of ``mission.link``."""

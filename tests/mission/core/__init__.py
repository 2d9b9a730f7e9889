"""Tests of ``mission.core``."""

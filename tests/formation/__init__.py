"""Tests of ``formation``."""

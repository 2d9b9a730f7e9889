"""Tests of ``companion``."""

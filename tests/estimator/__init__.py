"""Tests of ``estimator``."""

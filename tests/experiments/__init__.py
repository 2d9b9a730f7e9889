"""Tests of ``experiments`` (``swarmseek paper``, ``swarmseek simulate``, sweeps over seeds)."""

"""Tests of ``sitl_mock``, the simulated world."""

"""Tests of ``mission``, the ground station, one package per room."""

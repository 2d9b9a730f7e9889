"""Helpers shared by the tests of several rooms (whole missions, waiting, fuzzing, test PKI, SITL lookup)."""

"""Mock conformance: one scripted pymavlink session run against the mock and real SITL, compared."""

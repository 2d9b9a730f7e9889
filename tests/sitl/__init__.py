"""Tests against real firmware (PX4 SIH, ArduCopter SITL): ``SWARMSEEK_PX4_SITL`` / ``SWARMSEEK_ARDUPILOT_SITL``."""

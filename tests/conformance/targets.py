"""Where the conformance script runs: one mock vehicle or one real SITL instance.

:func:`observe_mock` starts a one-vehicle :class:`sitl_mock.fleet.MockFleet` of a personality
(PX4 style: the script listens on UDP as on PX4's API link; ArduPilot style: TCP as on SERIAL0)
on free ports, runs :func:`~conformance.script.run_script` and stops it. :func:`observe_sitl`
does the same with one real SITL instance started through :mod:`mission.sim.sitl_fleet`.
"""
from __future__ import annotations

from tests.conformance.script import run_script
from mission.sim.embedded import free_port_block

__all__ = ["MOCK_SPEEDUP", "SITL_SPEEDUP", "mock_param_names", "observe_mock", "observe_sitl"]

#: The mock runs this much faster than real time (its SimClock; telemetry carries its time).
MOCK_SPEEDUP = 4.0
#: Real SITL speed-up: ArduCopter's --speedup is sound (its scheduler runs in simulated time);
#: PX4 SIH keeps lock-step real time (PX4_SIM_SPEED_FACTOR also scales PX4's own timeouts,
#: but on a loaded 2-core host it lags behind and the estimator then complains), so 1.
SITL_SPEEDUP = {"ardupilot": 4.0, "px4": 1.0}


def mock_param_names(flavour: str) -> list[str]:
    """Names in the mock's parameter table of ``flavour`` (mock-only ``SIM_*`` names left out)."""
    from sitl_mock.ap_params import ardupilot_param_specs, px4_param_specs
    from sitl_mock.dynamics_params import DynamicsParams
    specs = (ardupilot_param_specs if flavour == "ardupilot" else px4_param_specs)(1, DynamicsParams())
    return [s.name for s in specs if not s.name.startswith("SIM_")]


def observe_mock(flavour: str, *, speedup: float = MOCK_SPEEDUP):
    """Run the script against one mock vehicle of personality ``flavour``."""
    import sitl_mock.clock as clock_mod
    import sitl_mock.fleet as fleet_mod
    base = free_port_block(30, kinds=("udp", "tcp"))
    fleet = fleet_mod.MockFleet(n=1, personality=flavour, clock=clock_mod.SimClock(speedup),
                                udp_base_port=base, udp_bind_base_port=base + 10, tcp_base_port=base + 20,
                                zenoh=False)
    fleet.start()
    try:
        mv = fleet.vehicles[0]
        uri = f"udpin:127.0.0.1:{mv.udp_send_port}" if flavour == "px4" else f"tcp:127.0.0.1:{mv.tcp_port}"
        return run_script(uri, mv.sysid, flavour, param_names=mock_param_names(flavour), wall_scale=1.0)
    finally:
        fleet.stop()


def observe_sitl(flavour: str, *, speedup: float | None = None, wall_scale: float = 3.0):
    """Run the script against one real SITL instance of ``flavour`` (found through its variable)."""
    from mission.sim.sitl_fleet import SitlFleet, SitlFleetConfig
    cfg = SitlFleetConfig(flavour=flavour, n=1, speedup=speedup or SITL_SPEEDUP[flavour],
                          ready_timeout_s=180.0).free()
    with SitlFleet(cfg) as fleet:
        v = fleet.vehicles[0]
        return run_script(v.connection, v.sysid, flavour, param_names=mock_param_names(flavour),
                          wall_scale=wall_scale)

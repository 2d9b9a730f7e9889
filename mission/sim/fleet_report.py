"""What the embedded mock fleet's vehicles refused (``swarmseek run``'s ``vehicle_rejections``).

Each mock autopilot counts the frames it drops (``MockVehicle.counters``, see
:class:`sitl_mock.autopilot.MockAutopilot`); :func:`vehicle_rejections` keeps the kinds that
mean "a frame was refused" (:data:`VEHICLE_REJECTION_KINDS`), per vehicle, non-zero only.
"""
from __future__ import annotations

__all__ = ["VEHICLE_REJECTION_KINDS", "vehicle_rejections"]

#: mock autopilot counters of refused frames: signing (``rx_unsigned``, ``rx_bad_signature``,
#: ``rx_replayed``, ``signing_setup_refused_armed``), damaged or foreign frames (``rx_bad_crc``,
#: ``rx_malformed``, ``rx_truncated``, ``rx_unknown_msg``, ``rx_parser_error``) and frames for
#: another system (``rx_not_for_us``)
VEHICLE_REJECTION_KINDS = ("rx_unsigned", "rx_bad_signature", "rx_replayed", "signing_setup_refused_armed",
                           "rx_bad_crc", "rx_malformed", "rx_truncated", "rx_unknown_msg",
                           "rx_parser_error", "rx_not_for_us")


def vehicle_rejections(fleet) -> dict[int, dict[str, int]]:
    """Frames each vehicle of ``fleet`` refused, by sysid then kind; vehicles that refused
    nothing are left out.

    Parameters
    ----------
    fleet : sitl_mock.fleet.MockFleet
        Its ``vehicles`` have ``sysid`` and ``counters``.
    """
    out: dict[int, dict[str, int]] = {}
    for v in fleet.vehicles:
        counters = v.counters
        kinds = {k: int(counters[k]) for k in VEHICLE_REJECTION_KINDS if counters.get(k)}
        if kinds:
            out[int(v.sysid)] = kinds
    return out

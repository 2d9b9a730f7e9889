"""Port layout of a mock fleet: vehicle ``i`` binds UDP ``udp_bind_base_port + i``, streams to
``udp_base_port + i`` and serves TCP on ``tcp_base_port + 10 i``; the two UDP ranges must not overlap."""
from __future__ import annotations

__all__ = ["check_port_base", "check_udp_ranges", "default_udp_bind_base_port"]

_PX4_UDP_BIND_BASE_PORT = 14580


def check_port_base(name: str, base: int, n: int, step: int) -> None:
    """Port ``base + step * i`` must be valid for every vehicle i (0 disables the transport)."""
    if base and not (1 <= base and base + step * (n - 1) <= 65535):
        raise ValueError(f"{name}={base} does not leave room for {n} vehicles (step {step})")


def default_udp_bind_base_port(n: int, udp_base_port: int = 14540) -> int:
    """PX4's 14580 when ``n`` send ports from ``udp_base_port`` end below it, else ``udp_base_port + n``.

    (With 14540 and 14580, vehicle 41 would stream to vehicle 1's own port.)
    """
    if udp_base_port + n <= _PX4_UDP_BIND_BASE_PORT or udp_base_port >= _PX4_UDP_BIND_BASE_PORT + n:
        return _PX4_UDP_BIND_BASE_PORT
    return udp_base_port + n


def check_udp_ranges(udp_base_port: int, udp_bind_base_port: int, n: int) -> None:
    """The send range ``udp_base_port + i`` and the bind range must not share a port."""
    if udp_base_port and udp_bind_base_port and abs(udp_base_port - udp_bind_base_port) < n:
        raise ValueError(f"udp_base_port={udp_base_port} and udp_bind_base_port={udp_bind_base_port} overlap for "
                         f"{n} vehicles (vehicle {abs(udp_base_port - udp_bind_base_port) + 1} would use another "
                         f"vehicle's port): put them at least {n} apart")

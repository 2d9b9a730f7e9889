"""A TCP relay between the ground station and one ArduCopter SITL instance's SERIAL0, with a switch
that cuts the link both ways (tests/sitl/test_sitl_faults_ardupilot_link.py).

The relay listens on a free port of 127.0.0.1 (the plan points the vehicle's connection there);
for each ground-station connection it opens one to the instance's SERIAL0 (``tcp:127.0.0.1:B+10k``)
and copies bytes both ways. Cut: every byte read either way is dropped (counted), the TCP
connections stay open, as a radio out of range (MAVLink frames cut in the middle are resynced by
the parsers). It runs in its own process (``python tests/sitl/ap_tcp_relay.py UPSTREAM_PORT``): a
thread of the test process shares its interpreter with the log polling and stalled for over 1 s
on a loaded host (tests/sitl/sitl_px4_fault_support.py). SIGUSR1 cuts, SIGUSR2 restores; on SIGTERM it
prints its counts as JSON and exits. Its first line is ``ready PORT`` (the port it listens on) or
the reason it could not start.
"""
from __future__ import annotations

import json
import select
import signal
import socket
import subprocess
import sys

__all__ = ["TcpRelay"]


class TcpRelay:
    """The relay process; a context manager (stopped, its counts kept, pass or fail).

    Parameters
    ----------
    upstream_port : int
        The instance's SERIAL0 TCP port on 127.0.0.1.

    Attributes
    ----------
    port : int
        The port the ground station connects to.
    counts : dict
        After :meth:`close`: bytes ``forwarded`` and ``dropped``, ``up`` (to the vehicle) and
        ``down``, and the number of ground-station ``connections``.
    """

    def __init__(self, upstream_port: int):
        self.upstream_port = upstream_port
        self.port = 0
        self.proc: subprocess.Popen | None = None
        self.counts: dict = {}

    def __enter__(self) -> TcpRelay:
        self.proc = subprocess.Popen([sys.executable, __file__, str(self.upstream_port)], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, start_new_session=True)
        line = self.proc.stdout.readline().strip()
        if not line.startswith("ready "):
            self.close()
            raise RuntimeError(f"the TCP relay did not start: {line}")
        self.port = int(line.split()[1])
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def connection(self) -> str:
        """The plan's connection string for the relayed vehicle."""
        return f"tcp:127.0.0.1:{self.port}"

    def cut(self, on: bool) -> None:
        """Cut (True) or restore (False) the link both ways."""
        self.proc.send_signal(signal.SIGUSR1 if on else signal.SIGUSR2)

    def close(self) -> None:
        """Stop the relay process (SIGTERM, then SIGKILL) and keep its counts."""
        if self.proc is None:
            return
        if self.proc.poll() is None:
            self.proc.terminate()
        try:
            out, _ = self.proc.communicate(timeout=10.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            out, _ = self.proc.communicate(timeout=10.0)
        for line in (out or "").splitlines():
            if line.startswith("{"):
                self.counts = json.loads(line)
        self.proc = None


def _pump(src: socket.socket, dst: socket.socket, way: str, state: dict, counts: dict) -> bool:
    """Copy what ``src`` has to ``dst`` (or drop it when cut); False when ``src`` closed."""
    try:
        data = src.recv(65536)
    except OSError:
        return False
    if not data:
        return False
    if state["cut"]:
        counts["dropped"][way] += len(data)
        return True
    try:
        dst.sendall(data)
    except OSError:
        return False
    counts["forwarded"][way] += len(data)
    return True


def _serve(gcs: socket.socket, upstream_port: int, state: dict, counts: dict) -> None:
    """Relay one ground-station connection until either side closes or SIGTERM."""
    try:
        vehicle = socket.create_connection(("127.0.0.1", upstream_port), timeout=10.0)
    except OSError as exc:
        print(f"cannot reach the vehicle at 127.0.0.1:{upstream_port}: {exc}", file=sys.stderr, flush=True)
        gcs.close()
        return
    vehicle.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    gcs.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    with gcs, vehicle:
        while not state["stop"]:
            try:
                ready, _, _ = select.select([gcs, vehicle], [], [], 0.1)
            except InterruptedError:
                continue
            for sock in ready:
                up = sock is gcs
                if not _pump(sock, vehicle if up else gcs, "up" if up else "down", state, counts):
                    return


def _relay_main(upstream_port: int) -> None:
    """The relay process (see :class:`TcpRelay`)."""
    state = {"cut": False, "stop": False}
    counts = {"forwarded": {"up": 0, "down": 0}, "dropped": {"up": 0, "down": 0}, "connections": 0}
    signal.signal(signal.SIGUSR1, lambda *_: state.update(cut=True))
    signal.signal(signal.SIGUSR2, lambda *_: state.update(cut=False))
    signal.signal(signal.SIGTERM, lambda *_: state.update(stop=True))
    listener = socket.socket()
    try:
        listener.bind(("127.0.0.1", 0))
        listener.listen(1)
    except OSError as exc:
        print(f"cannot listen on 127.0.0.1: {exc}", flush=True)
        return
    print(f"ready {listener.getsockname()[1]}", flush=True)
    while not state["stop"]:
        try:
            ready, _, _ = select.select([listener], [], [], 0.1)
        except InterruptedError:
            continue
        if ready:
            gcs, _ = listener.accept()
            counts["connections"] += 1
            _serve(gcs, upstream_port, state, counts)
    listener.close()
    print(json.dumps(counts), flush=True)


if __name__ == "__main__":
    _relay_main(int(sys.argv[1]))

"""free_port_block's leases: concurrent allocations never share a port, bound and leased ports are
skipped, and a port taken before the embedded run binds it ends in a one-line error (exit 1)."""
from __future__ import annotations

import json
import multiprocessing
import socket
import time

import pytest

from mission.cli import main as cli_main
from mission.sim.embedded import PORT_LEASE_S, free_port_block

_BLOCKS = 50
_SIZE = 8


def _allocate(lease_dir, barrier, out) -> None:
    """One process's allocations: ``_BLOCKS`` blocks of ``_SIZE`` UDP ports, none of them bound."""
    barrier.wait(timeout=60.0)
    bases = [free_port_block(_SIZE, lo=24000, hi=28000, lease_dir=lease_dir) for _ in range(_BLOCKS)]
    out.put(bases)


def _ports(bases) -> list[int]:
    return [b + i for b in bases for i in range(_SIZE)]


def test_two_processes_allocating_at_once_never_get_the_same_port(tmp_path):
    # nobody binds the ports: without the leases the bind check alone hands ~20 overlapping blocks
    # to these two processes (1/500 chance per pair of blocks in this 4000-port range)
    ctx = multiprocessing.get_context("spawn")
    barrier, out = ctx.Barrier(2), ctx.Queue()
    procs = [ctx.Process(target=_allocate, args=(str(tmp_path), barrier, out)) for _ in range(2)]
    for p in procs:
        p.start()
    results = [out.get(timeout=120.0) for _ in procs]
    for p in procs:
        p.join(timeout=30.0)
        assert p.exitcode == 0
    first, second = (_ports(bases) for bases in results)
    assert len(set(first)) == len(first) == _BLOCKS * _SIZE
    assert len(set(second)) == len(second) == _BLOCKS * _SIZE
    assert not set(first) & set(second)


def test_a_leased_port_is_not_handed_out_again_until_its_lease_ends(tmp_path):
    base = free_port_block(1, lo=26000, hi=28000, lease_dir=tmp_path)
    with pytest.raises(OSError, match=r"no block of 1 free loopback ports found in"):
        free_port_block(1, lo=base, hi=base + 1, lease_dir=tmp_path, tries=5)
    leases = json.loads((tmp_path / "leases.json").read_text())
    assert time.time() < leases[str(base)] <= time.time() + PORT_LEASE_S
    leases[str(base)] = 0.0  # expired
    (tmp_path / "leases.json").write_text(json.dumps(leases))
    assert free_port_block(1, lo=base, hi=base + 1, lease_dir=tmp_path) == base


def test_a_bound_port_is_skipped(tmp_path):
    base = free_port_block(2, kinds=("tcp",), lo=26000, hi=28000, lease_dir=tmp_path / "found")
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as held:
        held.bind(("127.0.0.1", base))
        with pytest.raises(OSError, match="no block of 1 free"):
            free_port_block(1, kinds=("tcp",), lo=base, hi=base + 1, lease_dir=tmp_path, tries=5)
        assert free_port_block(1, kinds=("tcp",), lo=base, hi=base + 2, lease_dir=tmp_path) == base + 1


def test_a_lease_file_cut_short_is_read_as_no_leases(tmp_path):
    (tmp_path / "leases.json").write_text('{"26001": 9e99, "2')
    base = free_port_block(1, lo=26000, hi=28000, lease_dir=tmp_path)
    assert str(base) in json.loads((tmp_path / "leases.json").read_text())


def test_run_with_its_zenoh_port_taken_says_so_in_one_line(tmp_path, capsys, monkeypatch):
    import mission.sim.embedded as embedded

    real = embedded.fleet_ports
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as squatter:
        squatter.bind(("127.0.0.1", 0))  # a process that is not ours takes the port after the check
        squatter.listen()
        taken = squatter.getsockname()[1]
        monkeypatch.setattr(embedded, "fleet_ports", lambda n, personality: {**real(n, personality),
                                                                             "zenoh_port": taken})
        code = cli_main(["run", "--n", "4", "--json", "--log-dir", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 1, err
    assert "cannot start the embedded fleet or zenoh" in err
    assert "Traceback" not in err

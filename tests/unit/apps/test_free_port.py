"""hercs' one free-port helper (`hercs.apps.launch.router.free_port`), which the router's
port-0 endpoints, the benchmarks and the tests all take their ports from."""

from __future__ import annotations

import socket

import pytest

from hercs.apps.launch.router import RouterListenError, free_port, pick_free_ports


@pytest.mark.parametrize(("host", "kind"), [("127.0.0.1", socket.SOCK_STREAM),
                                            ("0.0.0.0", socket.SOCK_STREAM),
                                            ("127.0.0.1", socket.SOCK_DGRAM)],
                         ids=["loopback-tcp", "every-address-tcp", "loopback-udp"])
def test_the_port_given_can_be_bound_on_that_host(host: str, kind: int) -> None:
    port = free_port(host, datagram=kind == socket.SOCK_DGRAM)
    assert 0 < port < 65536
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind((host, port))  # raises if the port was not free there


def test_port_zero_endpoints_get_free_ports_and_explicit_ones_are_kept() -> None:
    picked = pick_free_ports(["tcp/127.0.0.1:0", "tcp/127.0.0.1:7447", "udp/127.0.0.1:0"])
    assert picked[1] == "tcp/127.0.0.1:7447"
    for endpoint, kind in ((picked[0], socket.SOCK_STREAM), (picked[2], socket.SOCK_DGRAM)):
        proto, _, port = endpoint.rpartition(":")
        assert proto in ("tcp/127.0.0.1", "udp/127.0.0.1") and int(port) > 0
        with socket.socket(socket.AF_INET, kind) as sock:
            sock.bind(("127.0.0.1", int(port)))


def test_an_address_of_another_host_is_named_in_the_error() -> None:
    # 192.0.2.0/24 is TEST-NET-1 (RFC 5737): never one of this host's addresses
    with pytest.raises(RouterListenError, match=r"tcp/192\.0\.2\.1:0.*one of this host's"):
        pick_free_ports(["tcp/192.0.2.1:0"])

"""Free TCP ports on a host, chosen below the kernel's ephemeral range.

A port the kernel picks for bind(0) comes from the ephemeral range, the same range outgoing
connections take their local ports from: a server restarted on its old port found it taken by
some client's connection made while it was down (a CI run failed so). Below that range only
another listener can take a port, and the pick is random, so two callers rarely meet.
"""
from __future__ import annotations

import random
import socket

LOWEST = 10000
EXIT_PORT_IN_USE = 3  # the embedded server's exit code when its port is taken (EmbeddedServer retries)
_pick = random.SystemRandom()  # a test's random.seed() must not make processes pick alike


def ephemeral_range() -> tuple[int, int]:
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range") as f:
            low, high = (int(x) for x in f.read().split())
        return low, high
    except (OSError, ValueError):
        return 32768, 60999  # Linux's default; elsewhere only a guess


def bindable(host: str, port: int) -> bool:
    """Whether a listener could bind it now (SO_REUSEADDR, as asyncio's servers: a restarted
    server's old connections in TIME_WAIT do not count)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
            return True
        except OSError:
            return False


def free_port(host: str = "127.0.0.1", tries: int = 64) -> int:
    low = ephemeral_range()[0]
    if low - LOWEST > 1000:
        for _ in range(tries):
            port = _pick.randrange(LOWEST, low)
            if bindable(host, port):
                return port
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:  # no room below: the kernel picks
        s.bind((host, 0))
        return s.getsockname()[1]

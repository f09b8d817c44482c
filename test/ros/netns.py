"""A closed test network of Linux network namespaces: one namespace per "host", each with one veth
to a bridge that lives in its own namespace and has no link to the machine's interfaces, addresses
in a private subnet. Nothing is ever created in the machine's own namespace, so no packet a test
sends can leave the namespaces the test made; everything is removed on exit, also on failure.

Names carry the test run's pid and a counter, so parallel runs never collide."""

from __future__ import annotations

import functools
import gzip
import itertools
import os
import shutil
import signal
import subprocess
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field

from sdhn_sim.data_files import fastdds_profile

SUBNET = "10.213.0"  # /24, private; it only ever exists inside the bridge's closed network
FASTDDS_PROFILE = fastdds_profile()
_counter = itertools.count()


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    done = subprocess.run(["ip", *args], capture_output=True, text=True, check=False)
    if check and done.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)}: {done.stderr.strip()}")
    return done


def unavailable_reason() -> str | None:
    """Why namespaces cannot be made here (None when they can): not root, no ``ip``, or the kernel
    refuses ``ip netns add``."""
    if shutil.which("ip") is None:
        return "the `ip` tool (iproute2) is not installed"
    if os.geteuid() != 0:
        return "creating network namespaces needs root"
    name = f"sdhn-probe-{os.getpid()}-{next(_counter)}"
    done = _ip("netns", "add", name, check=False)
    if done.returncode != 0:
        return f"`ip netns add` failed: {done.stderr.strip()}"
    _ip("netns", "del", name, check=False)
    return None


@dataclass
class Host:
    name: str  # the host's role, e.g. "sim"
    netns: str  # its namespace
    addr: str  # its address on the test subnet
    port: str  # its veth on the bridge (the "switch port"), inside the bridge namespace

    def exec(self, args: Sequence[str], env: dict[str, str] | None = None) -> list[str]:
        """``args`` run inside this host's namespace, with ``env`` added to the environment."""
        sets = [f"{k}={v}" for k, v in (env or {}).items()]
        return ["ip", "netns", "exec", self.netns, "env", *sets, *args]


@dataclass
class Net:
    bridge_ns: str
    hosts: dict[str, Host] = field(default_factory=dict)

    def link(self, host: str, up: bool) -> None:
        """Pull (``up=False``) or plug back the host's cable: its bridge port goes down/up."""
        _ip("-n", self.bridge_ns, "link", "set", self.hosts[host].port, "up" if up else "down")

    def netem(self, host: str, args: Sequence[str]) -> None:
        """A ``tc netem`` profile (e.g. ``["delay", "5ms"]``) on both ends of the host's cable:
        its own eth0 (what it sends) and its bridge port (what it receives)."""
        h = self.hosts[host]
        for ns, dev in ((h.netns, "eth0"), (self.bridge_ns, h.port)):
            done = subprocess.run(["tc", "-n", ns, "qdisc", "add", "dev", dev, "root", "netem",
                                   *args], capture_output=True, text=True, check=False)
            if done.returncode != 0:
                raise RuntimeError(f"tc netem {' '.join(args)} on {dev}: {done.stderr.strip()}")

    def peers(self) -> str:
        """Every host's address, the value a user puts in ``ROS_STATIC_PEERS``."""
        return ";".join(h.addr for h in self.hosts.values())


@functools.cache
def netem_unavailable_reason() -> str | None:
    """Why ``tc qdisc ... netem`` cannot run here (None when it can), probed on a veth inside a
    throw-away namespace pair, never on the machine's own interfaces."""
    if shutil.which("tc") is None:
        return "the `tc` tool (iproute2) is not installed"
    reason = unavailable_reason()
    if reason is not None:
        return reason
    with closed_network(["probe"], multicast=False) as net:
        h = net.hosts["probe"]
        done = subprocess.run(["tc", "-n", h.netns, "qdisc", "add", "dev", "eth0", "root", "netem",
                               "delay", "5ms"], capture_output=True, text=True, check=False)
        if done.returncode != 0:
            return (f"tc netem unavailable: `tc qdisc add ... netem` says "
                    f"{done.stderr.strip()!r} (kernel {os.uname().release}{_netem_config()})")
    return None


def _netem_config() -> str:
    """What the running kernel's build configuration says about netem, when it is readable."""
    with suppress(OSError), gzip.open("/proc/config.gz", "rt") as f:
        for line in f:
            if "CONFIG_NET_SCH_NETEM" in line:
                return f", /proc/config.gz: {line.strip()}"
    return ""


def _kill_all(netns: str) -> None:
    pids = _ip("netns", "pids", netns, check=False).stdout.split()
    for pid in pids:
        with suppress(ProcessLookupError, ValueError):
            os.kill(int(pid), signal.SIGKILL)
    if pids:
        time.sleep(0.2)


@contextmanager
def closed_network(hosts: Sequence[str], multicast: bool = True) -> Iterator[Net]:
    """One namespace per host name, all on one bridge; ``multicast=False`` gives interfaces with
    multicast off and no multicast route (then discovery needs static peers)."""
    tag = f"{os.getpid() % 100000:05d}{next(_counter) % 100:02d}"
    net = Net(bridge_ns=f"sdhn-{tag}-br")
    made: list[str] = []
    try:
        _ip("netns", "add", net.bridge_ns)
        made.append(net.bridge_ns)
        _ip("-n", net.bridge_ns, "link", "add", "br0", "type", "bridge")
        # No IGMP querier exists on this closed network: without snooping, the bridge floods
        # multicast to every port, as an unmanaged switch does.
        _ip("-n", net.bridge_ns, "link", "set", "br0", "type", "bridge", "mcast_snooping", "0")
        _ip("-n", net.bridge_ns, "link", "set", "br0", "up")
        for i, name in enumerate(hosts):
            h = Host(name=name, netns=f"sdhn-{tag}-{i}", addr=f"{SUBNET}.{10 + i}",
                     port=f"v{tag}p{i}")
            _ip("netns", "add", h.netns)
            made.append(h.netns)
            # Both ends are created inside the new namespaces: nothing touches the machine's own.
            _ip("-n", h.netns, "link", "add", "eth0", "type", "veth", "peer", "name", h.port,
                "netns", net.bridge_ns)
            _ip("-n", net.bridge_ns, "link", "set", h.port, "master", "br0")
            _ip("-n", net.bridge_ns, "link", "set", h.port, "up")
            _ip("-n", h.netns, "link", "set", "lo", "up")
            _ip("-n", h.netns, "addr", "add", f"{h.addr}/24", "dev", "eth0")
            _ip("-n", h.netns, "link", "set", "eth0", "multicast", "on" if multicast else "off")
            _ip("-n", h.netns, "link", "set", "eth0", "up")
            if multicast:
                _ip("-n", h.netns, "route", "add", "224.0.0.0/4", "dev", "eth0")
            net.hosts[name] = h
        yield net
    finally:
        for ns in reversed(made):
            _kill_all(ns)
            _ip("netns", "del", ns, check=False)


def host_env(net: Net, static_peers: bool = False) -> dict[str, str]:
    """The environment of a node on one of the hosts, as a user sets it on a real network (the
    README's recipe): UDP only (on one machine Fast DDS would otherwise pass data through shared
    memory, around the network), discovery on the subnet by multicast, or by static peers, and
    the project's Fast DDS profile (0.5 s announcements, 100 ms writer heartbeats: what a reader
    lost while its link was down is asked for again within 0.1 s, not 3 s)."""
    env = {"FASTDDS_BUILTIN_TRANSPORTS": "UDPv4", "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET",
           "ROS_STATIC_PEERS": net.peers() if static_peers else "",
           "FASTRTPS_DEFAULT_PROFILES_FILE": str(FASTDDS_PROFILE)}
    return env

"""Hosts on one machine: Linux network namespaces joined to a hub by veth links.

:class:`HostLab` makes ``N`` host namespaces and one hub namespace (the
network between the hosts: routers, relays), each host joined to the hub by
a veth pair of its own, and the initial namespace joined to the hub by one
more (so the launcher can reach the hub without loss). Addresses: host ``i``
(1..N) is ``10.<net>.<i>.2`` and sees the hub at ``10.<net>.<i>.1``; the
launcher sees the hub at ``10.<net>.0.1``. Hosts reach each other only
through the hub's processes (no routing between links), as robots on a
wireless network reach each other through its infrastructure.

``loss`` drops that share of the packets in each direction of every host's
link, at random (``iptables -m statistic --mode random``, in the host's
namespace, on its veth device). Delay is not a kernel feature here (no
``sch_netem``): :mod:`services.relay` holds the bytes in user space.

Needs root (``CAP_NET_ADMIN``) and ``ip`` / ``iptables``; :func:`lab_problem`
says why a lab cannot be made. The lab removes everything it made on
:meth:`HostLab.close` (also on errors and on SIGINT/SIGTERM in the ``with``
block when the caller turns them into exceptions), ending first the
processes still running in its namespaces (they were started there by its
owner).
"""

from __future__ import annotations

import logging
import os
import shutil
import signal
import subprocess
import time
from dataclasses import dataclass

from sqpmpc.errors import ProblemError

__all__ = ["HostLab", "LabHost", "lab_problem"]

log = logging.getLogger("services.netns")


def _run(*argv: str) -> str:
    """Run a command; its stdout. :class:`ProblemError` naming it when it fails."""
    proc = subprocess.run(argv, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise ProblemError(f"{' '.join(argv)}: {proc.stderr.strip() or proc.returncode}")
    return proc.stdout


def lab_problem() -> str | None:
    """Why a :class:`HostLab` cannot be made on this machine (``None``: it can)."""
    if os.name != "posix" or not hasattr(os, "geteuid"):
        return "network namespaces need Linux"
    if os.geteuid() != 0:
        return "network namespaces and veth links need root (CAP_NET_ADMIN)"
    for tool in ("ip", "iptables"):
        if shutil.which(tool) is None:
            return f"{tool!r} is not installed"
    name = f"sqpmpc-probe-{os.getpid()}"
    try:
        _run("ip", "netns", "add", name)
    except ProblemError as exc:
        return f"cannot create a network namespace: {exc}"
    try:
        _run("ip", "netns", "exec", name, "ip", "link", "add", "probe0", "type", "veth",
             "peer", "name", "probe1")
    except ProblemError as exc:
        subprocess.run(["ip", "netns", "del", name], capture_output=True, check=False)
        return f"cannot create a veth link: {exc}"
    try:
        _run("ip", "netns", "exec", name, "iptables", "-A", "INPUT", "-m", "statistic",
             "--mode", "random", "--probability", "0.5", "-j", "ACCEPT")
    except ProblemError as exc:
        return f"iptables' statistic match does not work in a network namespace: {exc}"
    finally:
        subprocess.run(["ip", "netns", "del", name], capture_output=True, check=False)
    return None


@dataclass(frozen=True)
class LabHost:
    """One host of a :class:`HostLab`.

    Attributes
    ----------
    index
        1..N.
    namespace
        Its network namespace's name.
    address
        Its address on its link.
    hub_address
        The hub's address on its link (where the hub's relays listen for it).
    """

    index: int
    namespace: str
    address: str
    hub_address: str

    def argv(self, *command: str) -> list[str]:
        """``command`` run in this host's namespace."""
        return ["ip", "netns", "exec", self.namespace, *command]


class HostLab:
    """``hosts`` host namespaces and a hub (module docstring).

    Parameters
    ----------
    hosts
        Number of hosts, 1..250.
    loss
        Share of packets dropped in each direction of every host's link, 0..1.
    net
        Second byte of the lab's addresses ``10.<net>.x.y``, 1..254.
    tag
        Part of every name the lab makes (default: this process's id), so that
        labs of different processes do not clash.
    """

    def __init__(self, hosts: int, loss: float = 0.0, net: int = 201,
                 tag: str | None = None) -> None:
        if not 1 <= hosts <= 250:
            raise ProblemError(f"hosts: expected 1..250, got {hosts}")
        if not 0.0 <= loss < 1.0:
            raise ProblemError(f"loss: expected a share in [0, 1), got {loss}")
        if not 1 <= net <= 254:
            raise ProblemError(f"net: expected 1..254, got {net}")
        self.tag = tag or str(os.getpid())
        self.loss = float(loss)
        self.net = net
        self.hub = f"sqpmpc-{self.tag}-hub"
        self.hosts = [LabHost(i, f"sqpmpc-{self.tag}-h{i}", f"10.{net}.{i}.2",
                              f"10.{net}.{i}.1") for i in range(1, hosts + 1)]
        self.hub_address = f"10.{net}.0.1"
        """The hub's address as the launcher (initial namespace) sees it."""
        self._root_link = f"sqr{self.tag}"[:15]
        self._made: list[str] = []

    def hub_argv(self, *command: str) -> list[str]:
        """``command`` run in the hub's namespace."""
        return ["ip", "netns", "exec", self.hub, *command]

    def __enter__(self) -> HostLab:
        try:
            self.create()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _namespace(self, name: str) -> None:
        _run("ip", "netns", "add", name)
        self._made.append(name)
        _run("ip", "-n", name, "link", "set", "lo", "up")

    def create(self) -> None:
        """Make the namespaces, links, addresses and loss rules."""
        self._namespace(self.hub)
        _run("ip", "link", "add", self._root_link, "type", "veth", "peer", "name", "hub0",
             "netns", self.hub)
        _run("ip", "addr", "add", f"10.{self.net}.0.2/24", "dev", self._root_link)
        _run("ip", "link", "set", self._root_link, "up")
        _run("ip", "-n", self.hub, "addr", "add", f"{self.hub_address}/24", "dev", "hub0")
        _run("ip", "-n", self.hub, "link", "set", "hub0", "up")
        for h in self.hosts:
            self._namespace(h.namespace)
            hub_dev = f"hub{h.index}"
            _run("ip", "link", "add", "eth0", "netns", h.namespace, "type", "veth", "peer",
                 "name", hub_dev, "netns", self.hub)
            _run("ip", "-n", h.namespace, "addr", "add", f"{h.address}/24", "dev", "eth0")
            _run("ip", "-n", self.hub, "addr", "add", f"{h.hub_address}/24", "dev", hub_dev)
            _run("ip", "-n", h.namespace, "link", "set", "eth0", "up")
            _run("ip", "-n", self.hub, "link", "set", hub_dev, "up")
            for chain, flag in (("INPUT", "-i"), ("OUTPUT", "-o")):
                _run(*h.argv("iptables", "-A", chain, flag, "eth0"))  # counts every packet
                if self.loss > 0.0:
                    _run(*h.argv("iptables", "-A", chain, flag, "eth0", "-m", "statistic",
                                 "--mode", "random", "--probability", repr(self.loss),
                                 "-j", "DROP"))
        log.info("lab %s: %d hosts, loss %g per direction", self.tag, len(self.hosts),
                 self.loss)

    def packets(self) -> dict[int, tuple[int, int]]:
        """Per host: (packets onto or off its link so far, of which the loss rules dropped),
        both directions."""
        out = {}
        for h in self.hosts:
            total = dropped = 0
            for line in _run(*h.argv("iptables", "-L", "-v", "-n", "-x")).splitlines():
                fields = line.split()
                if "eth0" not in fields or not fields[0].isdigit():
                    continue
                if "DROP" in fields:
                    dropped += int(fields[0])
                else:
                    total += int(fields[0])
            out[h.index] = (total, dropped)
        return out

    def close(self) -> None:
        """End the processes left in the lab's namespaces, delete them (and so their links)."""
        for name in reversed(self._made):
            pids = subprocess.run(["ip", "netns", "pids", name], capture_output=True,
                                  text=True, check=False).stdout.split()
            for pid in pids:
                _signal(int(pid), signal.SIGKILL)
            if pids:
                log.warning("lab %s: ended %d processes left in %s", self.tag, len(pids), name)
        deadline = time.time() + 5.0
        for name in reversed(self._made):
            while subprocess.run(["ip", "netns", "pids", name], capture_output=True,
                                 text=True, check=False).stdout.split() \
                    and time.time() < deadline:
                time.sleep(0.05)
            proc = subprocess.run(["ip", "netns", "del", name], capture_output=True,
                                  text=True, check=False)
            if proc.returncode != 0:
                log.error("lab %s: could not delete %s: %s", self.tag, name,
                          proc.stderr.strip())
        self._made.clear()
        subprocess.run(["ip", "link", "del", self._root_link], capture_output=True, check=False)


def _signal(pid: int, sig: int) -> None:
    try:
        os.kill(pid, sig)
    except ProcessLookupError:
        pass

"""Controller overhead per fleet step over loopback SSH, against the raw round trip.

Why this benchmark: the fleet must not add much to the cost of moving its bytes. It
starts a throwaway OpenSSH server per host (``drivers.testing.sshd``, as the tests do),
runs a 4-arm fleet (2 hosts x 2 arms) whose agents run the twin's ``--no-physics`` mode
(canned PNGs, no simulation), and times ``observe()`` + ``execute(all 4 push)``.
The baseline moves the same reply frames through a bare ``cat`` exec channel on a
second connection to each host: per step and host, the observe reply's bytes and the
push reply's bytes each make one round trip (write them, read them back), both hosts
at once, driven as the fleet drives its agents (write to every host, then read every
host) and with nothing else: no framing, no agent, no decoding.

    ratio = fleet step time / raw round-trip time        (target <= 1.25)

Fleet and raw steps alternate in blocks (the 2-core test machine is shared and its
load drifts); medians are the figure to quote. ``--delay-ms D`` puts a relay process
in front of each sshd that delays every byte by D ms each way, to see the same ratio
at LAN/WAN latencies (both the fleet and the baseline go through it).

Where the time goes: two more baselines run in the same blocks, over the same kind
of bare channel, and their ratios to the raw round trip are printed too:

* ``python echo``: the channel runs this interpreter with a two-line read/write loop
  instead of ``cat``: the least any agent written in Python can cost;
* ``agent, bare channel``: the real agent (``--no-physics``), its request frames written
  and its reply frames read off a bare channel with no controller-side work but reading
  the length prefix: the agent's share. The fleet step minus this is the controller's.

Run: ``.venv/bin/python benchmarks/bench_ssh.py [--steps N] [--delay-ms D]`` (root or
any user that can run sshd; needs the Debian package openssh-server).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shlex
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from drivers import wire as p  # noqa: E402
from drivers.backends.twin import CannedTwinBackend  # noqa: E402
from drivers.backends.twin.twin_host import TwinHost  # noqa: E402
from drivers.host_fleet import HostFleet  # noqa: E402
from drivers.session import HostSession  # noqa: E402
from drivers.testing.sshd import SshServer, sshd_available  # noqa: E402
from drivers.transport import SshTransport  # noqa: E402
from testbed.core.host_config import HostConfig  # noqa: E402


def host_config(name: str, server: SshServer, port: int | None = None) -> HostConfig:
    return TwinHost(name=name, transport="ssh", address="127.0.0.1",
                      port=port or server.port,
                      user=server.user, key_file=str(server.client_key),
                      known_hosts=str(server.known_hosts), python=sys.executable,
                      workdir=str(ROOT), physics=False, deadline_s=10.0)


def reply_frames() -> list[bytes]:
    """The bytes one host's agent sends per step: an observe reply and a push reply."""
    backend = CannedTwinBackend(0)
    obs = p.make_observe_reply(1, backend.observe())
    push = p.make_push_reply(2, backend.push({"left": 1, "right": 1}))
    return [obs, push]


PYTHON_ECHO = "import os\nwhile d := os.read(0, 65536):\n    os.write(1, d)\n"


def cat_channel(server: SshServer, port: int | None = None,  # type: ignore[no-untyped-def]
                command: str = "cat"):
    import paramiko

    sock = socket.create_connection(("127.0.0.1", port or server.port))
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    client = paramiko.SSHClient()
    client.load_host_keys(str(server.known_hosts))
    client.set_missing_host_key_policy(paramiko.RejectPolicy())
    client.connect("127.0.0.1", port=port or server.port, username=server.user,
                   key_filename=str(server.client_key), sock=sock, allow_agent=False,
                   look_for_keys=False)
    chan = client.get_transport().open_session()  # type: ignore[union-attr]
    chan.exec_command(command)
    return client, chan


# --- an optional one-way delay in front of each sshd (the internet, roughly) --------
def relay_main(target_port: int, delay_s: float) -> int:
    """``--relay-for PORT``: forward 127.0.0.1:<printed port> to PORT, each byte late
    by ``delay_s`` in each direction. Runs in its own process (its threads would
    otherwise share the benchmark's GIL)."""
    import queue
    import threading

    srv = socket.create_server(("127.0.0.1", 0))
    print(srv.getsockname()[1], flush=True)

    def pipe(src: socket.socket, dst: socket.socket) -> None:
        q: queue.Queue[tuple[float, bytes] | None] = queue.Queue()

        def read() -> None:
            with contextlib.suppress(OSError):  # a reset at the end of the run
                while data := src.recv(65536):
                    q.put((time.monotonic() + delay_s, data))
            q.put(None)

        def write() -> None:
            with contextlib.suppress(OSError):
                while (item := q.get()) is not None:
                    time.sleep(max(item[0] - time.monotonic(), 0.0))
                    dst.sendall(item[1])
                dst.shutdown(socket.SHUT_WR)

        for fn in (read, write):
            threading.Thread(target=fn, daemon=True).start()

    while True:
        client, _ = srv.accept()
        upstream = socket.create_connection(("127.0.0.1", target_port))
        for sock in (client, upstream):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        pipe(client, upstream)
        pipe(upstream, client)


def start_relay(server: SshServer, delay_ms: float) -> tuple[subprocess.Popen[str], int]:
    proc = subprocess.Popen([sys.executable, __file__, "--relay-for", str(server.port),
                             "--delay-ms", str(delay_ms)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    port = int(proc.stdout.readline())
    key = server.host_key.with_suffix(".pub").read_text().split()
    with open(server.known_hosts, "a") as f:  # the same host key, seen at the relay port
        f.write(f"[127.0.0.1]:{port} {key[0]} {key[1]}\n")
    return proc, port


class RawEcho:
    """The baseline: one bare ``cat`` channel per host, driven the way the fleet drives
    its agents (write to every host, then read every host), with nothing else."""

    def __init__(self, servers: list[SshServer], frames: list[bytes],
                 ports: list[int | None], command: str = "cat") -> None:
        self.frames = frames
        self.chans = [cat_channel(s, port, command)
                      for s, port in zip(servers, ports, strict=True)]

    def step(self) -> None:
        chans = [c for _, c in self.chans]
        for f in self.frames:  # observe, then push: two round trips per step
            for chan in chans:
                chan.sendall(f)
            for chan in chans:
                got = 0
                while got < len(f):
                    chunk = chan.recv(len(f) - got)
                    if not chunk:
                        raise RuntimeError("cat channel closed")
                    got += len(chunk)

    def close(self) -> None:
        for client, chan in self.chans:
            chan.close()
            client.close()


def _read_exactly(chan, n: int) -> bytes:  # type: ignore[no-untyped-def]
    out = b""
    while len(out) < n:
        chunk = chan.recv(n - len(out))
        if not chunk:
            raise RuntimeError("channel closed")
        out += chunk
    return out


class AgentBare(RawEcho):
    """The real agent on a bare channel: request frames written, reply frames read with
    nothing done to them but reading their length (the agent's share of a step)."""

    def __init__(self, servers: list[SshServer], hosts: list[HostConfig],
                 ports: list[int | None]) -> None:
        self.frames = [p.make_request("observe", 7),
                       p.make_request("push", 8, faces={"left": 1, "right": 1})]
        self.chans = []
        for s, h, port in zip(servers, hosts, ports, strict=True):
            argv = HostSession(h, 0, 1.0).argv()
            client, chan = cat_channel(s, port, SshTransport.remote_command(h, argv))
            chan.sendall(p.make_request("hello", 1, version=p.PROTOCOL_VERSION, host=h.name))
            self.chans.append((client, chan))
            if self._reply(chan)[:4] != p.MAGIC:
                raise RuntimeError("the agent did not answer hello")

    @staticmethod
    def _reply(chan) -> bytes:  # type: ignore[no-untyped-def]
        prefix = _read_exactly(chan, p.PREFIX_BYTES)
        _, hlen, blen, _ = p.PREFIX.unpack(prefix)
        return prefix + _read_exactly(chan, hlen + blen)

    def step(self) -> None:
        chans = [c for _, c in self.chans]
        for f in self.frames:  # observe, then push, as the fleet step
            for chan in chans:
                chan.sendall(f)
            for chan in chans:
                self._reply(chan)

    def close(self) -> None:
        for _, chan in self.chans:
            chan.shutdown_write()  # EOF: the agent exits
        super().close()


def fleet_step(fleet: HostFleet, pushes: dict[str, int]) -> None:
    obs = fleet.observe()
    res = fleet.execute(pushes, [])
    bad = [r for r, v in {**obs, **res}.items() if type(v).__name__ == "Fault"]
    if bad:
        raise RuntimeError(f"faults during the benchmark: {bad}")


def timed(fn, n: int) -> list[float]:  # type: ignore[no-untyped-def]
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def summary(name: str, times: list[float]) -> str:
    ms = sorted(t * 1000 for t in times)
    return (f"{name:<34} mean {statistics.fmean(ms):6.3f} ms   median {statistics.median(ms):6.3f}"
            f"   p95 {ms[int(0.95 * (len(ms) - 1))]:6.3f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=2000, help="timed steps of each kind")
    ap.add_argument("--block", type=int, default=25,
                    help="alternate fleet and raw every BLOCK steps (the machine's load "
                         "drifts; both kinds see the same drift)")
    ap.add_argument("--delay-ms", type=float, default=0.0,
                    help="one-way delay added in front of each sshd by a relay process "
                         "(0: plain loopback, the target's setting)")
    ap.add_argument("--relay-for", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.relay_for is not None:
        return relay_main(args.relay_for, args.delay_ms / 1000.0)
    if not sshd_available():
        print("needs /usr/sbin/sshd and ssh-keygen (apt-get install openssh-server)")
        return 2
    frames = reply_frames()
    print(f"bytes per host per step: observe reply {len(frames[0])}, push reply "
          f"{len(frames[1])}; 2 hosts x 2 arms, {args.steps} steps each, blocks of "
          f"{args.block}; one-way delay {args.delay_ms:g} ms; {os.cpu_count()} CPUs, "
          f"load {os.getloadavg()[0]:.1f}")
    relays: list[subprocess.Popen[str]] = []
    with tempfile.TemporaryDirectory(prefix="bench-ssh-") as tmp:
        servers = [SshServer(Path(tmp) / f"host{i}") for i in range(2)]
        try:
            for s in servers:
                s.start()
            ports: list[int | None] = [None, None]
            if args.delay_ms > 0:
                for i, s in enumerate(servers):
                    proc, ports[i] = start_relay(s, args.delay_ms)
                    relays.append(proc)
            hosts = [host_config(f"cell{i}", s, ports[i]) for i, s in enumerate(servers)]
            with HostFleet(hosts, trial_seed=0) as fleet:
                if not all(st.connected for st in fleet.host_status().values()):
                    raise RuntimeError(f"hosts not connected: {fleet.host_status()}")
                pushes = dict.fromkeys(fleet.robot_names, 1)
                raw = RawEcho(servers, frames, ports)
                floors = {"python echo": RawEcho(servers, frames, ports,
                                                 f"{sys.executable} -c "
                                                 f"{shlex.quote(PYTHON_ECHO)}"),
                          "agent, bare channel": AgentBare(servers, hosts, ports)}
                try:
                    timed(lambda: fleet_step(fleet, pushes), 100)  # warm up all
                    timed(raw.step, 100)
                    for b in floors.values():
                        timed(b.step, 100)
                    fleet_t: list[float] = []
                    raw_t: list[float] = []
                    floor_t: dict[str, list[float]] = {k: [] for k in floors}
                    block_ratios: list[float] = []
                    for _ in range(max(args.steps // args.block, 1)):
                        f = timed(lambda: fleet_step(fleet, pushes), args.block)
                        r = timed(raw.step, args.block)
                        for k, b in floors.items():
                            floor_t[k] += timed(b.step, args.block)
                        fleet_t += f
                        raw_t += r
                        block_ratios.append(statistics.median(f) / statistics.median(r))
                finally:
                    raw.close()
                    for b in floors.values():
                        b.close()
        finally:
            for proc in relays:
                proc.kill()
                proc.wait()
            for s in servers:
                s.stop()
    print(summary("fleet step (observe + execute)", fleet_t))
    print(summary("raw round trip of the same bytes", raw_t))
    raw_med = statistics.median(raw_t)
    for k, t in floor_t.items():
        print(summary(k, t) + f"   ratio {statistics.median(t) / raw_med:.3f}")
    extra = (statistics.median(fleet_t) - statistics.median(raw_t)) * 1000
    ratio_med = statistics.median(fleet_t) / statistics.median(raw_t)
    ratio_mean = statistics.fmean(fleet_t) / statistics.fmean(raw_t)
    print(f"controller overhead per step: {extra:.3f} ms (medians)")
    print(f"ratio fleet/raw: {ratio_med:.3f} (medians), {ratio_mean:.3f} (means), "
          f"{statistics.median(block_ratios):.3f} (median of per-block ratios); "
          f"target <= 1.25")
    return 0


if __name__ == "__main__":
    sys.exit(main())

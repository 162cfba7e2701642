"""Controller overhead per fleet step over loopback SSH, against the raw round trip.

Why this benchmark: the fleet must not add much to the cost of moving its bytes. It
starts a throwaway OpenSSH server per host (``drivers.testing.sshd``, as the tests do),
runs a 4-arm fleet (2 hosts x 2 arms) whose agents run the twin's ``--no-physics`` mode
(canned PNGs, no simulation), and times ``observe()`` + ``execute(all 4 push)``.
The baseline moves the same reply frames through a bare ``cat`` exec channel on a
second connection to each host: per step and host, the observe reply's bytes and the
push reply's bytes each make one round trip (write them, read them back), both hosts
at once (one thread per host, as the fleet's hosts run at once).

    ratio = fleet step time / raw round-trip time        (target <= 1.25)

Run: ``.venv/bin/python benchmarks/bench_ssh.py [--steps N]`` (root or any user that can
run sshd; needs the Debian package openssh-server).
"""

from __future__ import annotations

import argparse
import socket
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from drivers import protocol as p  # noqa: E402
from drivers.backends.twin import CannedTwinBackend  # noqa: E402
from drivers.fleet import HostFleet  # noqa: E402
from drivers.testing.sshd import SshServer, sshd_available  # noqa: E402
from testbed.config import HostConfig  # noqa: E402


def host_config(name: str, server: SshServer) -> HostConfig:
    return HostConfig(name=name, transport="ssh", address="127.0.0.1", port=server.port,
                      user=server.user, key_file=str(server.client_key),
                      known_hosts=str(server.known_hosts), python=sys.executable,
                      workdir=str(ROOT), physics=False, deadline_s=10.0)


def reply_frames() -> list[bytes]:
    """The bytes one host's agent sends per step: an observe reply and a push reply."""
    backend = CannedTwinBackend(0)
    obs = p.make_observe_reply(1, backend.observe())
    push = p.make_push_reply(2, backend.push({"left": 1, "right": 1}))
    return [obs, push]


def cat_channel(server: SshServer):  # type: ignore[no-untyped-def]
    import paramiko

    sock = socket.create_connection(("127.0.0.1", server.port))
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    client = paramiko.SSHClient()
    client.load_host_keys(str(server.known_hosts))
    client.set_missing_host_key_policy(paramiko.RejectPolicy())
    client.connect("127.0.0.1", port=server.port, username=server.user,
                   key_filename=str(server.client_key), sock=sock, allow_agent=False,
                   look_for_keys=False)
    chan = client.get_transport().open_session()  # type: ignore[union-attr]
    chan.exec_command("cat")
    return client, chan


def echo(chan, data: bytes) -> None:  # type: ignore[no-untyped-def]
    chan.sendall(data)
    got = 0
    while got < len(data):
        chunk = chan.recv(len(data) - got)
        if not chunk:
            raise RuntimeError("cat channel closed")
        got += len(chunk)


class RawEcho:
    """The baseline: one bare ``cat`` channel per host, driven by one thread per host."""

    def __init__(self, servers: list[SshServer], frames: list[bytes]) -> None:
        self.frames = frames
        self.chans = [cat_channel(s) for s in servers]
        self._go = [threading.Event() for _ in self.chans]
        self._done = [threading.Event() for _ in self.chans]
        self._stop = False
        self._threads = [threading.Thread(target=self._run, args=(i,), daemon=True)
                         for i in range(len(self.chans))]
        for t in self._threads:
            t.start()

    def _run(self, i: int) -> None:
        chan = self.chans[i][1]
        while True:
            self._go[i].wait()
            self._go[i].clear()
            if self._stop:
                return
            for f in self.frames:
                echo(chan, f)
            self._done[i].set()

    def step(self) -> None:
        for e in self._go:
            e.set()
        for d in self._done:
            d.wait()
            d.clear()

    def close(self) -> None:
        self._stop = True
        for e in self._go:
            e.set()
        for client, chan in self.chans:
            chan.close()
            client.close()


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
    args = ap.parse_args()
    if not sshd_available():
        print("needs /usr/sbin/sshd and ssh-keygen (apt-get install openssh-server)")
        return 2
    frames = reply_frames()
    print(f"bytes per host per step: observe reply {len(frames[0])}, push reply "
          f"{len(frames[1])}; 2 hosts x 2 arms, {args.steps} steps each, blocks of "
          f"{args.block}")
    with tempfile.TemporaryDirectory(prefix="bench-ssh-") as tmp:
        servers = [SshServer(Path(tmp) / f"host{i}") for i in range(2)]
        try:
            for s in servers:
                s.start()
            hosts = [host_config(f"cell{i}", s) for i, s in enumerate(servers)]
            with HostFleet(hosts, trial_seed=0) as fleet:
                if not all(st.connected for st in fleet.host_status().values()):
                    raise RuntimeError(f"hosts not connected: {fleet.host_status()}")
                pushes = dict.fromkeys(fleet.robot_names, 1)
                raw = RawEcho(servers, frames)
                try:
                    timed(lambda: fleet_step(fleet, pushes), 100)  # warm up both
                    timed(raw.step, 100)
                    fleet_t: list[float] = []
                    raw_t: list[float] = []
                    block_ratios: list[float] = []
                    for _ in range(max(args.steps // args.block, 1)):
                        f = timed(lambda: fleet_step(fleet, pushes), args.block)
                        r = timed(raw.step, args.block)
                        fleet_t += f
                        raw_t += r
                        block_ratios.append(statistics.median(f) / statistics.median(r))
                finally:
                    raw.close()
            alone = RawEcho(servers[:1], frames)
            try:
                timed(alone.step, 100)
                single = timed(alone.step, 500)
            finally:
                alone.close()
        finally:
            for s in servers:
                s.stop()
    print(summary("fleet step (observe + execute)", fleet_t))
    print(summary("raw round trip, 2 hosts at once", raw_t))
    print(summary("raw round trip, 1 host alone", single))
    ratio_med = statistics.median(fleet_t) / statistics.median(raw_t)
    ratio_mean = statistics.fmean(fleet_t) / statistics.fmean(raw_t)
    print(f"overhead ratio: {ratio_med:.3f} (medians), {ratio_mean:.3f} (means), "
          f"{statistics.median(block_ratios):.3f} (median of per-block ratios); "
          f"target <= 1.25")
    return 0


if __name__ == "__main__":
    sys.exit(main())

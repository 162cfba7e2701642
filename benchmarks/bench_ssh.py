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


def bench_raw(servers: list[SshServer], frames: list[bytes], steps: int, warmup: int
              ) -> list[float]:
    chans = [cat_channel(s) for s in servers]
    barrier = threading.Barrier(len(chans) + 1)
    stop = False

    def run(chan) -> None:  # type: ignore[no-untyped-def]
        while True:
            barrier.wait()
            if stop:
                return
            for f in frames:
                echo(chan, f)
            barrier.wait()

    threads = [threading.Thread(target=run, args=(c,), daemon=True) for _, c in chans]
    for t in threads:
        t.start()
    times: list[float] = []
    for i in range(warmup + steps):
        t0 = time.perf_counter()
        barrier.wait()
        barrier.wait()
        if i >= warmup:
            times.append(time.perf_counter() - t0)
    stop = True
    barrier.wait()
    for client, chan in chans:
        chan.close()
        client.close()
    return times


def bench_raw_single(server: SshServer, frames: list[bytes], steps: int) -> list[float]:
    client, chan = cat_channel(server)
    times = []
    for i in range(steps + 20):
        t0 = time.perf_counter()
        for f in frames:
            echo(chan, f)
        if i >= 20:
            times.append(time.perf_counter() - t0)
    chan.close()
    client.close()
    return times


def bench_fleet(hosts: list[HostConfig], steps: int, warmup: int) -> list[float]:
    times: list[float] = []
    with HostFleet(hosts, trial_seed=0) as fleet:
        if not all(s.connected for s in fleet.host_status().values()):
            raise RuntimeError(f"hosts not connected: {fleet.host_status()}")
        pushes = dict.fromkeys(fleet.robot_names, 1)
        for i in range(warmup + steps):
            t0 = time.perf_counter()
            obs = fleet.observe()
            res = fleet.execute(pushes, [])
            if i >= warmup:
                times.append(time.perf_counter() - t0)
            bad = [r for r, v in {**obs, **res}.items() if type(v).__name__ == "Fault"]
            if bad:
                raise RuntimeError(f"faults during the benchmark: {bad}")
    return times


def summary(name: str, times: list[float]) -> str:
    ms = sorted(t * 1000 for t in times)
    return (f"{name:<34} mean {statistics.fmean(ms):6.3f} ms   median {statistics.median(ms):6.3f}"
            f"   p95 {ms[int(0.95 * (len(ms) - 1))]:6.3f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--warmup", type=int, default=50)
    ap.add_argument("--rounds", type=int, default=3, help="alternate fleet/raw this often")
    args = ap.parse_args()
    if not sshd_available():
        print("needs /usr/sbin/sshd and ssh-keygen (apt-get install openssh-server)")
        return 2
    frames = reply_frames()
    print(f"bytes per host per step: observe reply {len(frames[0])}, push reply "
          f"{len(frames[1])}; 2 hosts x 2 arms")
    with tempfile.TemporaryDirectory(prefix="bench-ssh-") as tmp:
        servers = [SshServer(Path(tmp) / f"host{i}") for i in range(2)]
        try:
            for s in servers:
                s.start()
            hosts = [host_config(f"cell{i}", s) for i, s in enumerate(servers)]
            fleet_t: list[float] = []
            raw_t: list[float] = []
            for _ in range(args.rounds):  # interleave: both see the same machine state
                fleet_t += bench_fleet(hosts, args.steps, args.warmup)
                raw_t += bench_raw(servers, frames, args.steps, args.warmup)
            single = bench_raw_single(servers[0], frames, args.steps)
        finally:
            for s in servers:
                s.stop()
    print(summary("fleet step (observe + execute)", fleet_t))
    print(summary("raw round trip, 2 hosts at once", raw_t))
    print(summary("raw round trip, 1 host alone", single))
    ratio_med = statistics.median(fleet_t) / statistics.median(raw_t)
    ratio_mean = statistics.fmean(fleet_t) / statistics.fmean(raw_t)
    print(f"ratio (median) {ratio_med:.3f}   ratio (mean) {ratio_mean:.3f}   target <= 1.25")
    return 0


if __name__ == "__main__":
    sys.exit(main())

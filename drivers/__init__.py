"""Everything that talks to a robot host (DESIGN.md section 2, ARCHITECTURE.md).

    fleet.py      HostFleet: the API the fleet loop calls (observe / execute / rest)
    session.py    one host's link, reconnect with backoff, heartbeat
    link.py       handshake and request/reply over a transport, with deadlines
    transport.py  LocalTransport (subprocess pipes), SshTransport (paramiko exec channel)
    protocol.py   frames and messages (png.py: the images)
    agent.py      python -m drivers.agent: runs ON the host, serves a backend
    backends/     HostBackend ABC, TwinBackend, YumiBackend (+ FakeYumiController)
    conformance.py  check_backend: the contract every backend must pass
    testing/      a throwaway OpenSSH server for tests and benchmarks

Importing ``drivers`` imports nothing heavy; pybullet and the ABB clients load only in
the agent that needs them.
"""

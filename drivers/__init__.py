"""Everything that talks to a robot host (docs/ARCHITECTURE.md, docs/notes/drivers.md).

    host_fleet.py HostFleet: the API the fleet loop calls (observe / execute / rest)
    session.py    one host's link, reconnect with backoff, heartbeat
    link.py       handshake and request/reply over a transport, with deadlines
    transport.py  LocalTransport (subprocess pipes), SshTransport (paramiko exec channel)
    wire.py       frames and messages (png.py: the images)
    agent.py      python -m drivers.agent: runs ON the host, serves a backend
    backends/     HostBackend ABC, TwinBackend, make_backend (the agent's lazy factory)
    yumi/         the ABB YuMi: YumiBackend, its controller clients, its camera
    conformance.py  check_backend: the contract every backend must pass
    testing/      test helpers: a throwaway OpenSSH server, FakeYumiController

Importing ``drivers`` imports nothing heavy; pybullet and the ABB clients load only in
the agent that needs them.
"""

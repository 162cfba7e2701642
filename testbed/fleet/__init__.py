"""The fleet: the loop of Fleet-DAgger timesteps, the allocator, the priority functions,
the registry of algorithms by name, and thresholds resolved from data.

Why a room: this is the algorithm of the paper, and it must run the same against twin
hosts, real hosts and a test's doubles, with scripted humans or people at a console:
so it talks to hosts, humans and the learner only through their contracts
(``testbed.core``) and imports no torch, no driver and no console.
"""

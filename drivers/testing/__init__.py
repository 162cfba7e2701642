"""Helpers for testing the drivers against real things (an OpenSSH server on loopback).

Importable by the tests and the benchmarks alike; nothing here runs in a trial.
"""

"""Benchmarks that users run as commands (``rbgp bench ...``); at the edge, like ``io`` and ``viz``.

They may import every core layer; nothing in the core imports them.
"""

"""Words for counts in messages: "1 demonstration", "2 demonstrations".

Like :mod:`rbgp_cli.errors` and :mod:`rbgp_cli.progress`, this module imports nothing, so every layer
may use it.
"""

from __future__ import annotations

__all__ = ["plural"]


def plural(n: int, word: str) -> str:
    """``n`` and ``word``, with an ``s`` unless ``n`` is 1: ``plural(1, "fold") == "1 fold"``."""
    return f"{n} {word}{'' if n == 1 else 's'}"

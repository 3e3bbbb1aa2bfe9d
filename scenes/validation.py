"""One error type for a bad setting, shared by every config: it names the field it concerns.

The command line maps ``field`` to its option and prints ``detail`` in one line.
"""

from __future__ import annotations

#: Largest seed of any config: seeds feed NumPy's SeedSequence and the manifests (32 bits).
MAX_SEED = 2**32 - 1


class FieldError(ValueError):
    """An invalid value of the config field ``field``; ``detail`` says why and what is allowed."""

    def __init__(self, field_name: str, message: str) -> None:
        super().__init__(f"{field_name}: {message}")
        self.field = field_name
        self.detail = message

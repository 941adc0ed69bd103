"""The root of the project's errors, and the one error type a malformed or unacceptable
message raises.

Every error the project raises on purpose derives from :class:`DmttError` (and, where it says
what kind of value was wrong, from the built-in class a caller would expect too: ``ValueError``,
``RuntimeError``, ``FileNotFoundError``), so a command line catches the root once and prints
one line (``sim_cluster`` and ``edge_node``); ``tests/test_errors.py`` keeps it so. It lives in
the lowest layer (``protocol``) so every layer can derive from it.
"""


class DmttError(Exception):
    """An error of this project: bad input (a file, a field, a message) or a state it cannot
    go on from; its text says what and where. Programming errors stay built-in exceptions."""


class ProtocolError(DmttError, ValueError):
    """A message that cannot be accepted; ``reason`` is a short machine-readable tag.

    ``reason`` is one of ``REASONS`` so that a runtime can count rejections by cause;
    the message text says what exactly was wrong.
    """

    REASONS = (
        "malformed",  # not msgpack, wrong structure, wrong types or shapes
        "version",  # schema version we do not speak
        "non_finite",  # NaN or inf in a numeric field
        "oversize",  # payload or a count beyond the configured limits
        "unknown_network",  # network name is not ours
        "unknown_sender",  # sender is not a configured neighbour
        "forged_source",  # payload sender does not match the key expression
        "key",  # key expression does not parse
    )

    def __init__(self, reason: str, detail: str):
        if reason not in self.REASONS:
            raise ValueError(f"unknown ProtocolError reason {reason!r}")
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail

"""The one error type a malformed or unacceptable message raises."""


class ProtocolError(ValueError):
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
        "stale",  # replayed / too old frame
        "key",  # key expression does not parse
    )

    def __init__(self, reason: str, detail: str):
        if reason not in self.REASONS:
            raise ValueError(f"unknown ProtocolError reason {reason!r}")
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail

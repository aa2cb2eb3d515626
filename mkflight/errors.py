"""The package's error types: one root, one subclass per concern.

Every message names the thing that failed (a config key, a port, a field) and the
error that caused it is chained with ``raise ... from err``. The CLI turns them into
one ``error:`` line and an exit code; nothing below the CLI prints or exits.
"""


class MkflightError(Exception):
    """Root of every error mkflight raises on purpose."""


class ConfigError(MkflightError):
    """A configuration file or ``--set`` override is invalid (exit 2)."""


class ProtocolError(MkflightError):
    """A value cannot be encoded or a frame cannot be decoded."""


class CommandRangeError(ProtocolError, ValueError):
    """An outgoing command field is non-finite, non-integral or outside its wire range."""


class LinkError(MkflightError):
    """A serial link failed at run time: no answer, device vanished, I/O error (exit 1)."""


class PortNotFoundError(LinkError):
    """The serial device path does not exist (a usage error: exit 2)."""


class ReplayError(MkflightError):
    """A recording cannot be replayed."""


class PreflightError(MkflightError):
    """A pre-flight check failed: the vehicle does not take off (exit 1); names the check."""

    def __init__(self, check: str, detail: str) -> None:
        super().__init__(f"pre-flight check '{check}' failed: {detail}")
        self.check = check
        self.detail = detail


class FlightError(MkflightError):
    """The flight ended on a failure (the FC vanished, a task crashed); exit 1 after landing."""

"""How a run ended (or that it still runs): the closed set of summary.json's ``status``.

The string in summary.json stays what crews' scripts already read: the status's value, then,
where the status has one, ``": "`` and the reason (``"aborted: battery reserve: ..."``,
``"refused_preflight: battery: ..."``, ``"finished"``). Code decides on :class:`RunStatus`,
never on a prefix of that string.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum


class RunStatus(str, Enum):
    """Where a run stands."""

    RUNNING = "running"
    FINISHED = "finished"
    ABORTED = "aborted"  # the mission stopped early (its reason says why); the vehicle left safely or was handed over
    REFUSED_PREFLIGHT = "refused_preflight"  # the pre-flight gate refused the arm command: nothing flew
    INTERRUPTED = "interrupted"  # the operator stopped the program (Ctrl-C)
    FAILED = "failed"  # the program failed (an exception)


#: the statuses whose run did not do its job: the command exits non-zero
UNSUCCESSFUL = frozenset({RunStatus.ABORTED, RunStatus.REFUSED_PREFLIGHT})


@dataclass(frozen=True)
class RunOutcome:
    """A :class:`RunStatus` and its ``reason`` (None: it has none)."""

    status: RunStatus = RunStatus.RUNNING
    reason: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "status", RunStatus(self.status))  # a bad status is refused, named

    @classmethod
    def parse(cls, text: str) -> RunOutcome:
        """summary.json's ``status`` read back (a report built from the files); ValueError naming
        the status when it is none of :class:`RunStatus`."""
        head, sep, reason = text.partition(": ")
        return cls(RunStatus(head.strip()), reason if sep else None)

    def __str__(self) -> str:
        """summary.json's ``status``."""
        return self.status.value if self.reason is None else f"{self.status.value}: {self.reason}"

    @property
    def unsuccessful(self) -> bool:
        """Whether the mission did not do its job (aborted, refused before arming)."""
        return self.status in UNSUCCESSFUL

"""The localization methods by name: the one place Python spells them.

Every caller (the CLI's ``--method`` choices, the pipeline, the flight loop, the replay, the
studies) reads :class:`LocalizationMethod`; the compiled core's ``Method`` (fusion_core) is the
other side of the boundary, and ``tests/test_localization_method.py`` checks both list the same
names (``ir.localize_methods()``).
"""

from __future__ import annotations

from enum import Enum


class LocalizationMethod(str, Enum):
    """A localization method of ``ir.localize``: the paper's four on the cloud alone, and the
    bounded fifth (the LiDAR's line, its ends from the detection boxes).

    A ``str`` (``LocalizationMethod.BOUNDED == "bounded"``), so it is passed to the core, written
    to a report and offered as a CLI choice as its name. (Python 3.10 has no ``enum.StrEnum``;
    ``__str__`` gives the value as StrEnum's does.)"""

    DBSCAN = "dbscan"
    RANSAC = "ransac"
    DBSCAN_RANSAC = "dbscan+ransac"
    DBSCAN_PCA = "dbscan+pca"
    BOUNDED = "bounded"

    def __str__(self) -> str:
        return str(self.value)

    @property
    def needs_boxes(self) -> bool:
        """Whether the method reads the detection boxes (only the bounded one)."""
        return self is LocalizationMethod.BOUNDED

    @property
    def label(self) -> str:
        """The name a table or a plot legend shows."""
        return _LABELS[self]

    @classmethod
    def parse(cls, value: str) -> LocalizationMethod:
        """``value`` as a method; ``ValueError`` naming the argument and the choices otherwise."""
        try:
            return cls(value)
        except ValueError:
            choices = ", ".join(m.value for m in cls)
            raise ValueError(f"method: must be one of {choices}, got {value!r}") from None


_LABELS = {
    LocalizationMethod.DBSCAN: "DBSCAN",
    LocalizationMethod.RANSAC: "RANSAC",
    LocalizationMethod.DBSCAN_RANSAC: "DBSCAN + RANSAC",
    LocalizationMethod.DBSCAN_PCA: "DBSCAN + PCA",
    LocalizationMethod.BOUNDED: "Bounded (cam.)",
}

#: The product's method (``insulator-rs inspect --method``'s default): the flight, the replay and
#: the clutter study use it unless told otherwise.
DEFAULT_METHOD = LocalizationMethod.BOUNDED


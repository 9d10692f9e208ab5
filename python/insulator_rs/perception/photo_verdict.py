"""A photo's verdict: fit for inspection or not, and why. Decided once, read everywhere.

The flight decides it when it checks a photo on itself
(:func:`~insulator_rs.perception.photo_check.check_photo`) and writes it into the photo's record
of ``summary.json`` (``check.verdict``, :meth:`PhotoVerdict.to_json`). The log line, the retake,
``report.html`` and the scorer's ``score.json`` all read that one verdict
(:func:`verdict_of_record`); none of them decides again, so they cannot disagree.

A verdict always says why: an unfit photo names at least one :class:`Reason`, a fit one
:attr:`Reason.PASSED` (what it passed). Two different things are named apart:
*motion blur* (px, the smear of one exposure computed from the vehicle's speed: a figure of
:mod:`~insulator_rs.perception.photo_quality`) and *not sharp* (:attr:`Reason.NOT_SHARP`, the
Laplacian variance measured on the photo itself).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from enum import Enum
from typing import Any


class Fitness(str, Enum):
    """Is the photo fit for a defect inspection?"""

    FIT = "fit"
    UNFIT = "unfit"


class Reason(str, Enum):
    """Why a photo got its verdict; the value is the human text, the name the JSON code."""

    PASSED = "insulator detected whole, centred, big enough and sharp"
    NOT_DETECTED = "no insulator detected"
    NOT_WHERE_PLANNED = "string not where planned"
    NOT_IN_VIEW = "string not in front of the camera"
    CUT = "cut by the border"
    TOO_SMALL = "too small"
    OFF_CENTRE = "off centre"
    NOT_SHARP = "not sharp (the string's region lacks fine detail)"
    DETECTOR_ERROR = "detector failed"

    @property
    def text(self) -> str:
        """The reason in words, as the log and the report print it."""
        return str(self.value)


#: Texts an older summary wrote for a reason whose words have changed since.
_OLD_TEXTS = {"blurred": Reason.NOT_SHARP, "not sharp (Laplacian variance too low)": Reason.NOT_SHARP}


@dataclass(frozen=True)
class PhotoVerdict:
    """``fitness`` and its ``reasons`` (never empty: :attr:`Reason.PASSED` alone for a fit photo,
    one or more of the others for an unfit one); ``detail``: what the reasons cannot say (the
    detector's error message), None when nothing."""

    fitness: Fitness
    reasons: tuple[Reason, ...]
    detail: str | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.fitness, Fitness):
            raise TypeError(f"fitness: expected a Fitness, got {type(self.fitness).__name__}")
        if not self.reasons or not all(isinstance(r, Reason) for r in self.reasons):
            raise ValueError(f"reasons: expected a non-empty tuple of Reason, got {self.reasons!r}")
        if self.fitness is Fitness.FIT and self.reasons != (Reason.PASSED,):
            raise ValueError(f"reasons: a fit photo's reason is PASSED alone, got {self.reasons!r}")
        if self.fitness is Fitness.UNFIT and Reason.PASSED in self.reasons:
            raise ValueError("reasons: an unfit photo cannot have PASSED among its reasons")
        if len(set(self.reasons)) != len(self.reasons):
            raise ValueError(f"reasons: each reason once, got {self.reasons!r}")

    @classmethod
    def passed(cls) -> PhotoVerdict:
        """The verdict of a photo that passed every check."""
        return cls(Fitness.FIT, (Reason.PASSED,))

    @classmethod
    def unfit(cls, reasons: Iterable[Reason], detail: str | None = None) -> PhotoVerdict:
        """The verdict of a photo unfit for ``reasons`` (at least one)."""
        return cls(Fitness.UNFIT, tuple(reasons), detail)

    @property
    def fit(self) -> bool:
        return self.fitness is Fitness.FIT

    @property
    def unfit_reasons(self) -> list[str]:
        """The reasons in words when unfit, [] when fit (what a retake or a table lists)."""
        return [] if self.fit else [r.text for r in self.reasons]

    def describe(self) -> str:
        """One line: ``fit`` or ``unfit: cut by the border, too small`` (and the detail)."""
        if self.fit:
            return "fit"
        return "unfit: " + ", ".join(self.unfit_reasons) + (f" ({self.detail})" if self.detail else "")

    def to_json(self) -> dict[str, Any]:
        """The verdict as ``summary.json`` holds it: ``{"fitness", "reasons": [{"code", "text"}],
        "detail"}`` (the text is for a reader of the file; the code is what is read back)."""
        return {"fitness": self.fitness.value,
                "reasons": [{"code": r.name, "text": r.text} for r in self.reasons],
                "detail": self.detail}

    @classmethod
    def from_json(cls, doc: Any) -> PhotoVerdict:
        """The verdict :meth:`to_json` wrote; ValueError naming the field that is not one."""
        if not isinstance(doc, Mapping):
            raise ValueError(f"verdict: expected an object, got {type(doc).__name__}")
        try:
            fitness = Fitness(doc.get("fitness"))
        except ValueError:
            raise ValueError(f"verdict.fitness: expected 'fit' or 'unfit', got {doc.get('fitness')!r}") from None
        raw = doc.get("reasons")
        if not isinstance(raw, list):
            raise ValueError(f"verdict.reasons: expected a list, got {type(raw).__name__}")
        reasons = []
        for k, r in enumerate(raw):
            code = r.get("code") if isinstance(r, Mapping) else None
            if not isinstance(code, str) or code not in Reason.__members__:
                raise ValueError(f"verdict.reasons[{k}]: unknown reason code {code!r}")
            reasons.append(Reason[code])
        detail = doc.get("detail")
        if detail is not None and not isinstance(detail, str):
            raise ValueError(f"verdict.detail: expected a string or null, got {type(detail).__name__}")
        return cls(fitness, tuple(reasons), detail)


def verdict_of_record(photo: Mapping[str, Any]) -> PhotoVerdict | None:
    """The verdict in a ``summary.json`` photo record (its ``check.verdict``); None for a photo
    that was not checked. A record from before the verdict was written (``check.fit`` and the
    reasons' texts) is read as the same verdict. ValueError names what is malformed."""
    check = photo.get("check")
    if check is None:
        return None
    if not isinstance(check, Mapping):
        raise ValueError(f"photo {photo.get('file')!r}: check: expected an object, got {type(check).__name__}")
    if "verdict" in check:
        try:
            return PhotoVerdict.from_json(check["verdict"])
        except ValueError as exc:
            raise ValueError(f"photo {photo.get('file')!r}: check.{exc}") from None
    if check.get("fit"):
        return PhotoVerdict.passed()
    reasons = []
    for text in check.get("reasons") or []:
        by_text = {r.text: r for r in Reason} | _OLD_TEXTS
        if text not in by_text:
            raise ValueError(f"photo {photo.get('file')!r}: check.reasons: unknown reason {text!r}")
        reasons.append(by_text[text])
    if not reasons:
        raise ValueError(f"photo {photo.get('file')!r}: check: unfit without a reason")
    return PhotoVerdict.unfit(reasons, check.get("error"))


def fit_tally(photos: Iterable[Mapping[str, Any]]) -> tuple[int, set[Any]]:
    """(how many of ``photos``, summary.json records, are fit, the ``insulator_id`` of each
    insulator with at least one fit photo), read off their verdicts."""
    fit = [p for p in photos if (v := verdict_of_record(p)) is not None and v.fit]
    return len(fit), {p.get("insulator_id") for p in fit}

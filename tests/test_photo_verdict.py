"""One verdict per photo (perception/photo_verdict.py): decided once by the flight, written into
summary.json, and read, never decided again, by the log, report.html and the scorer."""

from __future__ import annotations

import json
import re
from html.parser import HTMLParser

import pytest

from insulator_rs.app.cli import main
from insulator_rs.perception.photo_verdict import Fitness, PhotoVerdict, Reason, verdict_of_record
from helpers.flights import ARGS, small_scene


def test_round_trip_through_json_for_every_reason():
    verdicts = [PhotoVerdict.passed(), PhotoVerdict.unfit([Reason.DETECTOR_ERROR], "RuntimeError: CUDA")]
    verdicts += [PhotoVerdict.unfit([r]) for r in Reason if r is not Reason.PASSED]
    verdicts.append(PhotoVerdict.unfit([Reason.CUT, Reason.TOO_SMALL, Reason.NOT_SHARP]))
    for v in verdicts:
        doc = json.loads(json.dumps(v.to_json()))
        assert PhotoVerdict.from_json(doc) == v
        assert all(r["text"] for r in doc["reasons"])  # every reason has words


@pytest.mark.parametrize("fitness, reasons", [
    (Fitness.UNFIT, ()),                                  # unfit without a reason
    (Fitness.FIT, ()),                                    # no reason at all
    (Fitness.FIT, (Reason.CUT,)),                         # fit for an unfit reason
    (Fitness.UNFIT, (Reason.PASSED, Reason.CUT)),         # unfit and passed
    (Fitness.UNFIT, (Reason.CUT, Reason.CUT)),            # a reason twice
])
def test_a_verdict_without_a_true_reason_cannot_be_made(fitness, reasons):
    with pytest.raises(ValueError, match="reasons"):
        PhotoVerdict(fitness, reasons)


@pytest.mark.parametrize("doc, field", [
    ({"fitness": "good", "reasons": []}, "verdict.fitness"),
    ({"fitness": "unfit", "reasons": "cut"}, "verdict.reasons"),
    ({"fitness": "unfit", "reasons": [{"code": "SMUDGED"}]}, r"verdict.reasons\[0\]"),
    ({"fitness": "unfit", "reasons": []}, "reasons"),
])
def test_a_bad_verdict_in_a_file_is_named(doc, field):
    with pytest.raises(ValueError, match=field):
        PhotoVerdict.from_json(doc)


def test_a_record_from_before_the_verdict_reads_as_the_same_verdict():
    old = {"file": "a.jpg", "check": {"fit": False, "reasons": ["cut by the border", "blurred"], "error": None}}
    assert verdict_of_record(old) == PhotoVerdict.unfit([Reason.CUT, Reason.NOT_SHARP])
    assert verdict_of_record({"file": "b.jpg", "check": {"fit": True, "reasons": []}}) == PhotoVerdict.passed()
    assert verdict_of_record({"file": "c.jpg"}) is None  # not checked
    with pytest.raises(ValueError, match="c.jpg.*unknown reason 'smudged'"):
        verdict_of_record({"file": "c.jpg", "check": {"fit": False, "reasons": ["smudged"]}})


def test_motion_blur_and_not_sharp_are_named_apart():
    """"blur" (px, the exposure's smear) is a figure; the photo's own sharpness is NOT_SHARP."""
    assert "blur" not in Reason.NOT_SHARP.text and "sharp" in Reason.NOT_SHARP.text
    assert all("blur" not in r.text for r in Reason)


class _Figures(HTMLParser):
    """Each photo figure of report.html: its data-verdict and its verdict's text."""

    def __init__(self) -> None:
        super().__init__()
        self.photos: dict[str, dict[str, str]] = {}
        self._file: str | None = None
        self._in_verdict = False

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        if tag == "figure" and a.get("data-file"):
            self._file = str(a["data-file"])
            self.photos[self._file] = {"code": str(a.get("data-verdict")), "text": ""}
        elif tag == "span" and self._file and "verdict" in (a.get("class") or "").split():
            self._in_verdict = True

    def handle_endtag(self, tag: str) -> None:
        if tag == "span":
            self._in_verdict = False
        elif tag == "figure":
            self._file = None

    def handle_data(self, data: str) -> None:
        if self._in_verdict and self._file:
            self.photos[self._file]["text"] += data


@pytest.mark.slow
def test_log_summary_report_and_score_agree_on_every_photo(tmp_path, capsys):
    """A small flight: every photo's verdict as the log line says it, as summary.json holds it,
    as report.html shows it and as score.json carries it: one and the same."""
    scene, mission = small_scene(tmp_path)
    out = tmp_path / "report"
    args = [a for a in ARGS if a != "--quiet"]
    assert main(["inspect", "--scene", str(scene), "--mission", str(mission), "--out", str(out), *args]) == 0
    log = capsys.readouterr().out
    assert re.search(r"^scoring: \d+ photos: the true string projected", log, flags=re.M)  # progress, no render
    said = dict(re.findall(r"photo (images/\S+\.jpg): .*; checked on the photo: (.+)$", log, flags=re.M))
    summary = json.loads((out / "summary.json").read_text())
    score = json.loads((out / "score.json").read_text())
    page = _Figures()
    page.feed((out / "report.html").read_text(encoding="utf-8"))

    photos = summary["photos"]
    assert photos, "the small flight took no photo"
    scored = {p["file"]: p for p in score["photos"]}
    assert set(said) == set(scored) == set(page.photos) == {p["file"] for p in photos}
    for p in photos:
        verdict = verdict_of_record(p)
        assert verdict is not None
        assert said[p["file"]] == verdict.describe()
        assert PhotoVerdict.from_json(scored[p["file"]]["verdict"]) == verdict
        shown = page.photos[p["file"]]
        assert shown["code"] == verdict.fitness.value
        assert shown["text"] == ("fit for inspection" if verdict.fit
                                 else "not fit: " + ", ".join(verdict.unfit_reasons)
                                 + (f" ({verdict.detail})" if verdict.detail else ""))
    fit = sum(1 for p in photos if verdict_of_record(p).fit)  # type: ignore[union-attr]
    assert summary["photo_checks"]["fit"] == fit
    assert re.search(rf'id="card-fit"><div class="v">{fit}<', (out / "report.html").read_text(encoding="utf-8"))

"""The main job's wall time, as a new user meets it: ``insulator-rs inspect`` at its defaults.

    python benches/main_job.py                 # tower A then tower B, full-size 12 MP photos
    python benches/main_job.py tower_b         # one scene
    python benches/main_job.py tower_b -- --detector standin   # extra inspect options after --

Each run starts the installed command in a fresh process (as a user types it), with scoring
included, and reads its output as it comes: the wall time, the longest stretch without a line
(a user sees nothing for that long), and what ``summary.json`` and ``score.json`` say. The figures
are printed against the targets a user is promised (tower A within 3 minutes, tower B within 2,
no silence over 10 s) as ratios; nothing here fails on time: speed is reported, not asserted.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

#: What the README promises on the 2-core reference machine: wall seconds per scene, scoring in.
TARGET_S = {"tower_a": 180.0, "tower_b": 120.0}
#: The longest a user should wait for the next progress line.
MAX_SILENCE_S = 10.0


@dataclass(frozen=True)
class Run:
    scene: str
    wall_s: float
    longest_silence_s: float
    silence_after: str
    rc: int
    found: int | None
    in_scene: int | None
    false_finds: int | None
    photos: int | None


def inspect_once(scene: str, out: Path, extra: list[str]) -> Run:
    """Run ``insulator-rs inspect --scene SCENE --out OUT [extra]`` and time it line by line."""
    exe = shutil.which("insulator-rs")
    if exe is None:
        raise SystemExit("main_job: the insulator-rs command is not on PATH (pip install the package first)")
    cmd = [exe, "inspect", "--scene", scene, "--out", str(out), *extra]
    t0 = last = time.monotonic()
    longest, after = 0.0, "(start)"
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1) as proc:
        assert proc.stdout is not None
        for line in proc.stdout:
            now = time.monotonic()
            if now - last > longest:
                longest = now - last
                after = line.strip()[:80]
            last = now
            sys.stdout.write(f"  [{now - t0:6.1f} s] {line}")
        rc = proc.wait()
    end = time.monotonic()
    if end - last > longest:
        longest, after = end - last, "(the end)"
    summary = _read(out / "summary.json")
    score = _read(out / "score.json")
    found, matched = score.get("insulators_found"), score.get("insulators_matched")
    false_finds = found - matched if isinstance(found, int) and isinstance(matched, int) else None
    return Run(scene=scene, wall_s=end - t0, longest_silence_s=longest, silence_after=after, rc=rc,
               found=matched, in_scene=score.get("insulators_in_scene"), false_finds=false_finds,
               photos=len(summary.get("photos", [])))


def _read(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def main(argv: list[str]) -> int:
    extra: list[str] = []
    if "--" in argv:
        cut = argv.index("--")
        argv, extra = argv[:cut], argv[cut + 1:]
    scenes = argv or ["tower_a", "tower_b"]
    runs = []
    with tempfile.TemporaryDirectory(prefix="main_job_") as tmp:
        for scene in scenes:
            print(f"== insulator-rs inspect --scene {scene} {' '.join(extra)}".rstrip())
            runs.append(inspect_once(scene, Path(tmp) / scene, extra))
    print()
    print(f"{'scene':8} {'wall':>8} {'target':>7} {'ratio':>6} {'silence':>8}  found   false  photos  rc")
    for r in runs:
        target = TARGET_S.get(r.scene)
        ratio = f"{r.wall_s / target:6.2f}" if target else "     -"
        print(f"{r.scene:8} {r.wall_s:7.1f}s {target or 0:6.0f}s {ratio} {r.longest_silence_s:7.1f}s  "
              f"{r.found}/{r.in_scene}  {r.false_finds!s:>5}  {r.photos!s:>6}  {r.rc}")
        print(f"         longest silence ended with: {r.silence_after}")
    print(f"(ratio = wall / target: at most 1.00 meets the promise; silence target {MAX_SILENCE_S:.0f} s)")
    return 0 if all(r.rc == 0 for r in runs) else 1


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))

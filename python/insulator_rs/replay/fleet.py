"""Many recorded flights re-processed in parallel on Ray, plus a fleet summary.

Each flight is one Ray task running :func:`~insulator_rs.replay.batch.replay_one`, the
function a single ``replay`` runs, into ``OUT/<recording name>/``. ``address=None`` starts a
local Ray with ``workers`` CPUs (and stops it after); an address joins a running cluster
(every node needs insulator_rs installed; the recordings and ``OUT`` on storage all nodes
see). ``workers=1`` without an address runs the flights one after another in this process
(no Ray needed).

Each flight's read-ahead runs the network on as many threads as it has cores
(``ReplayOptions.network_threads``, when not given): its share of a local Ray's (the cores this
process may use over ``workers``, at least one), and one on a cluster, where Ray fills every CPU
of a node with a task. Left at one a core, N flights on N cores ran N x N network threads. On
the 2-core development box the share measured no faster (2 flights on 2 workers: 23.3 s against
23.1 s, both slower than the two one after the other by Ray's start-up); it bounds the threads
where a node has many cores.

``fleet_summary.json``: per flight its status, insulators found, detector and errors where
ground truth exists; per tower (its GPS position) the insulators each flight found.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path
from typing import Any

from insulator_rs.replay.batch import ReplayOptions, replay_one
from insulator_rs.replay.lookahead import default_workers
from insulator_rs.report.jsonfile import write_json


def _name(path: Path, used: set[str]) -> str:
    base = path.stem if path.is_file() else path.name
    name, k = base, 1
    while name in used:
        k += 1
        name = f"{base}_{k}"
    used.add(name)
    return name


def replay_fleet(flights: list[Path], out: Path, options: ReplayOptions, *, workers: int = 1,
                 address: str | None = None) -> dict[str, Any]:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    used: set[str] = set()
    jobs = [(Path(f).resolve(), (out / _name(Path(f), used)).resolve()) for f in flights]
    options = replace(options, progress=False)  # bars from parallel tasks interleave
    if workers == 1 and address is None:
        summaries = [replay_one(f, o, options) for f, o in jobs]
    else:
        summaries = _on_ray(jobs, options, workers, address)
    for (_, o), summary in zip(jobs, summaries):
        summary["out"] = str(o)
    fleet = fleet_summary(summaries)
    write_json(out / "fleet_summary.json", fleet)
    return fleet


def _on_ray(jobs: list[tuple[Path, Path]], options: ReplayOptions, workers: int,
            address: str | None) -> list[dict[str, Any]]:
    import ray

    started = False
    if not ray.is_initialized():
        # Local workers import insulator_rs from where this process does.
        env = {"env_vars": {"PYTHONPATH": os.pathsep.join(filter(None, [str(Path(__file__).resolve().parents[2]),
                                                                           os.environ.get("PYTHONPATH", "")]))}}
        if address is None:
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False, runtime_env=env,
                     configure_logging=False)
        else:
            ray.init(address=address, log_to_driver=False, configure_logging=False)
        started = True
    if options.network_threads is None:
        options = replace(options, network_threads=fleet_network_threads(workers, address))
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(replay_one)
        refs = [task.remote(str(f), str(o), options) for f, o in jobs]
        results = []
        for (f, o), ref in zip(jobs, refs):
            try:
                results.append(ray.get(ref))
            except Exception as exc:  # a worker died (out of memory, killed): that flight failed
                results.append({"status": f"failed: Ray task: {type(exc).__name__}: {exc}", "recording": str(f),
                                "insulators_found": 0, "insulators": []})
        return results
    finally:
        if started:
            ray.shutdown()


def fleet_network_threads(workers: int, address: str | None) -> int:
    """Network threads for each flight of a fleet: a local Ray's cores shared among its
    ``workers`` (at least one each); one on a cluster (a task holds one CPU of its node)."""
    if address is not None:
        return 1
    return max(1, default_workers() // max(1, workers))


def fleet_summary(summaries: list[dict[str, Any]]) -> dict[str, Any]:
    flights = []
    towers: dict[str, list[dict[str, Any]]] = {}
    for s in summaries:
        rec = {k: s.get(k) for k in ("recording", "out", "status", "detector", "scene", "tower", "insulators_found",
                                     "flight_time_s", "wall_time_s", "speed_vs_real_time")}
        flights.append(rec)
        if s.get("tower"):
            towers.setdefault(s["tower"], []).append({"recording": s["recording"],
                                                      "insulators_found": s.get("insulators_found", 0)})
    return {"flights": flights, "flights_ok": sum(1 for f in flights if f["status"] == "finished"),
            "towers": towers,
            "detectors": sorted({str(f["detector"]) for f in flights if f.get("detector")})}

"""Missions: load a scenario file, run it in the simulator, and turn the log into a per-step
table, a summary and the numbers the figures need."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from swarmraft import __version__
from swarmraft.estimation.bounds import gnss_covariance, swarm_crb
from swarmraft.estimation.registry import one_line
from swarmraft.experiments.config import ConfigError, read_toml
from swarmraft.experiments.tables import write_rows
from swarmraft.sim.mission import MissionLog, run_mission
from swarmraft.sim.scenario import Scenario

STEP_COLUMNS = (
    "step",
    "t",
    "drone",
    "alive",
    "spoofed",
    "outage",
    "missing",
    "faulty",
    "committed",
    "truth_x",
    "truth_y",
    "truth_z",
    "reported_x",
    "reported_y",
    "reported_z",
    "verified_x",
    "verified_y",
    "verified_z",
    "error_gnss",
    "error_ins_alone",
    "error_swarmraft",
    "bound",
    "leader",
    "term",
    "latency_ms",
    "raft_messages",
    "report_messages",
    "status",
)


def load_scenario(path: str | Path, **overrides: Any) -> Scenario:
    """A scenario from a TOML file; a bad file is a one-line ConfigError naming the field."""
    path = Path(path)
    data = read_toml(path, "--scenario")
    data.update({k: v for k, v in overrides.items() if v is not None})
    try:
        return Scenario(**data)
    except ValidationError as exc:
        raise ConfigError(f"{path.name}: {one_line(exc, '')}") from None


@dataclass(frozen=True)
class MissionResult:
    log: MissionLog
    errors: dict[str, np.ndarray]  # (S, n) each: gnss, ins_alone, swarmraft, bound
    summary: dict[str, Any]


def error_series(log: MissionLog) -> dict[str, np.ndarray]:
    """Per step and drone: error of the raw GNSS output, of INS alone, of SwarmRaft's
    committed position, and the swarm Cramér-Rao bound (sqrt of the trace) with the spoofed,
    jammed and silent drones' GNSS excluded."""
    sc = log.scenario

    def err(x: np.ndarray) -> np.ndarray:
        return np.linalg.norm(x - log.truth, axis=2)

    trusted = ~log.spoofed & ~log.outage & log.alive
    measured = np.ones((len(log.t), sc.drones, sc.drones), dtype=bool)
    bound = np.full(log.spoofed.shape, np.nan)
    if sc.ranging.sigma > 0 and sc.gnss.sigma_h > 0 and sc.gnss.sigma_v > 0:
        C = swarm_crb(
            log.truth, trusted, measured, gnss_covariance(sc.gnss.sigma_h, sc.gnss.sigma_v), sc.ranging.sigma
        )
        bound = np.sqrt(np.trace(C, axis1=2, axis2=3))
    return {
        "gnss": err(log.gnss),
        "ins_alone": err(log.ins_alone),
        "swarmraft": err(log.verified),
        "bound": bound,
    }


def _mean(values: np.ndarray) -> float | None:
    """Mean of the finite values, rounded to mm; None when there are none (exact data has no
    bound, a drone may have no committed position)."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    return round(float(v.mean()), 3) if v.size else None


def _runs(mask: np.ndarray) -> int:
    """Longest run of True."""
    best = cur = 0
    for v in mask:
        cur = cur + 1 if v else 0
        best = max(best, cur)
    return best


def summarize(log: MissionLog, errors: dict[str, np.ndarray]) -> dict[str, Any]:
    sc = log.scenario
    n, S = sc.drones, len(log.t)
    spoof_ever = log.spoofed.any(axis=0)
    honest = ~spoof_ever
    # every node's records agree on the steps both applied
    digests: dict[int, str] = {}
    agree = True
    for recs in log.node_records.values():
        for step, d in recs:
            agree &= digests.setdefault(step, d) == d
    committed = int(log.committed.sum())
    per_step_min = 2 * (n - 1)
    detections = []
    for k_sp, sp in enumerate(sc.spoof):
        k0 = int(np.ceil(sp.start_s / sc.dt_s - 1e-9))
        for d in sp.drones:
            i = d - 1
            hit = np.flatnonzero(log.faulty[k0:, i] & log.committed[k0:])
            if hit.size:
                k = k0 + int(hit[0])
                after = np.arange(k, S)
                after = after[log.committed[after] & log.spoofed[after, i]]
                with np.errstate(invalid="ignore", divide="ignore"):
                    ratio = errors["swarmraft"][after, i] / errors["bound"][after, i]
                ratio = ratio[np.isfinite(ratio)]
                detections.append(
                    {
                        "spoof": k_sp,
                        "kind": sp.kind,
                        "drone": d,
                        "detected": True,
                        "time_to_detect_s": round(float(log.t[k] - sp.start_s), 3),
                        "reported_error_at_detection_m": round(float(errors["gnss"][k, i]), 3),
                        "mean_error_after_m": _mean(errors["swarmraft"][after, i]),
                        "mean_bound_after_m": _mean(errors["bound"][after, i]),
                        "p95_error_to_bound_after": round(float(np.percentile(ratio, 95)), 3)
                        if ratio.size
                        else None,
                    }
                )
            else:
                detections.append({"spoof": k_sp, "kind": sp.kind, "drone": d, "detected": False})
    outages = []
    for o in sc.outage:
        k0 = int(np.ceil(o.start_s / sc.dt_s - 1e-9))
        k1 = len(log.t) if o.end_s is None else min(int(np.ceil(o.end_s / sc.dt_s - 1e-9)), len(log.t))
        for d in o.drones:
            i = d - 1
            outages.append(
                {
                    "drone": d,
                    "from_s": o.start_s,
                    "to_s": o.end_s,
                    "mean_error_swarmraft_m": _mean(errors["swarmraft"][k0:k1, i]),
                    "mean_error_ins_alone_m": _mean(errors["ins_alone"][k0:k1, i]),
                    "mean_bound_m": _mean(errors["bound"][k0:k1, i]),
                }
            )
    hon_mask = honest[None, :] & log.committed[:, None] & log.alive
    fp = float(log.faulty[hon_mask].mean()) if hon_mask.any() else 0.0
    raft_per = float(log.raft_messages[log.committed].mean()) if committed else float("nan")
    return {
        "scenario": sc.name,
        "version": __version__,
        "seed": sc.seed,
        "drones": n,
        "steps": S,
        "detector": sc.protocol.detector,
        "detector_params": {
            k: (round(v, 4) if isinstance(v, float) else v) for k, v in log.detector_params.items()
        },
        "committed_steps": committed,
        "skipped_steps": S - committed,
        "longest_skipped_run": _runs(~log.committed),
        "records_identical_on_all_nodes": bool(agree),
        "honest_error_gnss_m": _mean(errors["gnss"][:, honest]),
        "honest_error_swarmraft_m": _mean(errors["swarmraft"][:, honest]),
        "honest_bound_m": _mean(errors["bound"][:, honest]),
        "honest_false_positive_rate": round(fp, 5),
        "detections": detections,
        "outages": outages,
        "latency_ms_median": round(float(np.nanmedian(log.latency_ms)), 2),
        "latency_ms_p99": round(float(np.nanpercentile(log.latency_ms, 99)), 2),
        "raft_messages_per_committed_step": round(raft_per, 2),
        "raft_minimum_per_step": per_step_min,
        "reports_per_step": round(float(log.report_messages.mean()), 2),
        "events": [f"{t:.1f} s: {e}" for t, e in log.events],
    }


def step_rows(log: MissionLog, errors: dict[str, np.ndarray]) -> list[dict[str, Any]]:
    rows = []
    for k in range(len(log.t)):
        for i in range(log.scenario.drones):
            tr, rp, vf = log.truth[k, i], log.reported[k, i], log.verified[k, i]
            rows.append(
                {
                    "step": k,
                    "t": round(float(log.t[k]), 3),
                    "drone": i + 1,
                    "alive": log.alive[k, i],
                    "spoofed": log.spoofed[k, i],
                    "outage": log.outage[k, i],
                    "missing": log.missing[k, i],
                    "faulty": log.faulty[k, i],
                    "committed": log.committed[k],
                    "truth_x": tr[0],
                    "truth_y": tr[1],
                    "truth_z": tr[2],
                    "reported_x": rp[0],
                    "reported_y": rp[1],
                    "reported_z": rp[2],
                    "verified_x": vf[0],
                    "verified_y": vf[1],
                    "verified_z": vf[2],
                    "error_gnss": errors["gnss"][k, i],
                    "error_ins_alone": errors["ins_alone"][k, i],
                    "error_swarmraft": errors["swarmraft"][k, i],
                    "bound": errors["bound"][k, i],
                    "leader": log.leader[k],
                    "term": log.term[k],
                    "latency_ms": log.latency_ms[k],
                    "raft_messages": log.raft_messages[k],
                    "report_messages": log.report_messages[k],
                    "status": log.status[k],
                }
            )
    return rows


def run_and_write(sc: Scenario, out: Path, progress: Any = None) -> MissionResult:
    """Run a mission and write steps.csv, summary.json and scenario.json into ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    log = run_mission(sc, progress)
    errors = error_series(log)
    summary = summarize(log, errors)
    write_rows(out / "steps.csv", STEP_COLUMNS, step_rows(log, errors))
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    (out / "scenario.json").write_text(json.dumps(sc.model_dump(mode="json"), indent=2) + "\n")
    return MissionResult(log, errors, summary)

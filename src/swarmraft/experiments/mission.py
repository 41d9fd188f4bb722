"""Missions: load a scenario file, run it in the simulator, and turn the log into a per-step
table, a summary and the numbers the figures need."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from swarmraft import __version__
from swarmraft.estimation.bounds import gnss_covariance, swarm_crb
from swarmraft.estimation.registry import one_line
from swarmraft.experiments.config import ConfigError, read_toml
from swarmraft.experiments.tables import write_rows, write_text
from swarmraft.sim.mission import MissionLog, run_mission
from swarmraft.sim.scenario import Scenario, find_scenario, shipped_scenarios
from swarmraft.world.geometry import true_distances

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
    "wrong_partition",
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
    "error_ins_aligned",
    "error_swarmraft",
    "snapshot_bound",
    "hpl",
    "vpl",
    "misleading",
    "leader",
    "term",
    "latency_ms",
    "raft_messages",
    "report_messages",
    "status",
)

#: steps.csv's last column when drones join or leave (`MissionLog.member`); other missions'
#: files stay as they were
MEMBER_COLUMN = "member"


def step_columns(log: MissionLog) -> tuple[str, ...]:
    return STEP_COLUMNS + ((MEMBER_COLUMN,) if log.member is not None else ())


def load_scenario(path: str | Path, **overrides: Any) -> Scenario:
    """A scenario from a TOML file, or a shipped scenario by name (``demo``); a bad file is a
    one-line ConfigError naming the field."""
    path = find_scenario(path)
    if not path.exists():
        raise ConfigError(
            f"--scenario: no file {path} and no shipped scenario of that name "
            f"(shipped: {', '.join(shipped_scenarios())})"
        )
    data = read_toml(path, "--scenario")
    data.update({k: v for k, v in overrides.items() if v is not None})
    try:
        return Scenario(**data)
    except ValidationError as exc:
        raise ConfigError(f"{path.name}: {one_line(exc, '', Scenario)}") from None


@dataclass(frozen=True)
class MissionResult:
    log: MissionLog
    errors: dict[str, np.ndarray]  # (S, n) each: see error_series
    summary: dict[str, Any]


#: A spoofed drone's detection is *sustained* from the first step at which it is flagged in
#: every judged step (committed, the drone alive and heard) of the SUSTAIN_S seconds that
#: start there, all within its spoof (so a spoof shorter than that has none).
SUSTAIN_S = 3.0

BOUND_NOTE = (
    "snapshot bound: the Cramér-Rao bound of one step's measurements alone (honest GNSS and "
    "every range, the faulty set known); SwarmRaft also carries the previous record as a "
    "prior, so it can be below this bound"
)


def _in_range(truth: np.ndarray, max_range: float | None) -> np.ndarray:
    """(S, n, n) bool: the pairs of drones at ``truth`` (S, n, 3) that range each other, as
    `world.ranging` decides it (nothing beyond ``max_range``; None: every pair), a block of
    steps at a time (a 60 s mission of 256 drones holds 315 MB of distances)."""
    S, n, _ = truth.shape
    if max_range is None:
        return np.ones((S, n, n), dtype=bool)
    out = np.empty((S, n, n), dtype=bool)
    step = max(1, 2**21 // max(1, n * n))
    for lo in range(0, S, step):
        out[lo : lo + step] = ~(true_distances(truth[lo : lo + step]) > max_range)
    return out


def error_series(log: MissionLog) -> dict[str, np.ndarray]:
    """Per step and drone: error of the raw GNSS output, of INS alone (never reset), of INS
    aligned to the truth at the start of the drone's GNSS outage (nan outside outages), of
    SwarmRaft's committed position, and the snapshot bound (sqrt of the trace of the swarm
    Cramér-Rao bound of that step's measurements alone, with the spoofed, jammed and silent
    drones' GNSS excluded, and only the ranges the scenario's radios reach: none between
    drones farther apart than its ``max_range``). A drone outside the swarm (not joined yet,
    or left) has none of them (nan): it takes no part in the bound's measurements either."""
    sc = log.scenario
    member = log.in_swarm()

    def err(x: np.ndarray) -> np.ndarray:
        e = np.linalg.norm(x - log.truth, axis=2)
        return e if log.member is None else np.where(member, e, np.nan)

    trusted = ~log.spoofed & ~log.outage & log.alive
    bound = np.full(log.spoofed.shape, np.nan)
    if sc.ranging.sigma > 0 and sc.gnss.sigma_h > 0 and sc.gnss.sigma_v > 0:
        cov = gnss_covariance(sc.gnss.sigma_h, sc.gnss.sigma_v)
        # the swarm of each step: every drone, or (drones joining and leaving) the drones in
        # it, one bound per distinct swarm
        swarms = [np.ones(sc.drones, bool)] if log.member is None else np.unique(member, axis=0)
        for swarm in swarms:
            rows = np.flatnonzero((member == swarm).all(axis=1))
            idx = np.flatnonzero(swarm)
            sub = np.ix_(rows, idx)
            measured = _in_range(log.truth[sub], sc.ranging.max_range)
            C = swarm_crb(log.truth[sub], trusted[sub], measured, cov, sc.ranging.sigma)
            bound[sub] = np.sqrt(np.trace(C, axis1=2, axis2=3))
    return {
        "gnss": err(log.gnss),
        "ins_alone": err(log.ins_alone),
        "ins_aligned": err(log.ins_aligned),
        "swarmraft": err(log.verified),
        "snapshot_bound": bound,
    }


def judged(log: MissionLog) -> np.ndarray:
    """(S, n) bool: the drone's flag in the step's record can be judged: the step has a
    record, the drone is alive and its report reached the leader (a silent drone is placed
    from ranges and neither flagged nor cleared; a drone outside the swarm sends none)."""
    return log.committed[:, None] & log.alive & ~log.missing


def wrong_partition(log: MissionLog) -> np.ndarray:
    """(S,) bool: committed steps whose flags differ from the spoofed set among the judged
    drones (an honest drone flagged, or a spoofed one not flagged)."""
    return (judged(log) & (log.faulty != log.spoofed)).any(axis=1)


def _stat(values: np.ndarray, f: Callable[[np.ndarray], float] = np.mean, digits: int = 3) -> float | None:
    """``f`` (default the mean) of the finite values, rounded to ``digits`` (default: mm);
    None when there are none (exact data has no bound, a drone may have no committed
    position, a run may commit no step)."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    return round(float(f(v)), digits) if v.size else None


def _max(values: np.ndarray) -> float | None:
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    return round(float(v.max()), 3) if v.size else None


def _runs(mask: np.ndarray) -> int:
    """Longest run of True."""
    best = cur = 0
    for v in mask:
        cur = cur + 1 if v else 0
        best = max(best, cur)
    return best


def time_ranges(t: np.ndarray, mask: np.ndarray) -> list[tuple[float, float]]:
    """The runs of True in ``mask`` as (first, last) times, s."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(int), [0]])))
    return [
        (round(float(t[a]), 3), round(float(t[b - 1]), 3))
        for a, b in zip(edges[::2], edges[1::2], strict=True)
    ]


def _step_of(sc: Scenario, t_s: float, S: int) -> int:
    return min(int(np.ceil(t_s / sc.dt_s - 1e-9)), S)


def _spoof_detection(log: MissionLog, errors: dict[str, np.ndarray], k_sp: int, drone: int) -> dict[str, Any]:
    """How one spoofed drone was flagged over its spoof: the share of judged steps flagged,
    the first and the sustained detection (SUSTAIN_S), and its error from the spoof's start."""
    sc = log.scenario
    sp = sc.spoof[k_sp]
    S, i = len(log.t), drone - 1
    k0 = _step_of(sc, sp.start_s, S)
    k1 = S if sp.end_s is None else _step_of(sc, sp.end_s, S)
    steps = np.arange(k0, k1)
    seen = judged(log)[steps, i]
    flagged = log.faulty[steps, i] & seen
    hold = max(1, int(round(SUSTAIN_S / sc.dt_s)))
    first = sustained = None
    if flagged.any():
        first = int(steps[np.flatnonzero(flagged)[0]])
        for j in np.flatnonzero(flagged):
            window = slice(j, j + hold)
            if j + hold <= len(steps) and (flagged[window] | ~seen[window]).all():
                sustained = int(steps[j])
                break
    err, bound = errors["swarmraft"][steps, i], errors["snapshot_bound"][steps, i]
    ok = np.isfinite(err) & np.isfinite(bound) & (bound > 0)
    ratio = err[ok] / bound[ok]
    since = slice(0, 0) if first is None else slice(first - k0, None)  # from the first detection

    def after(k: int | None) -> float | None:
        return None if k is None else round(float(log.t[k] - sp.start_s), 3)

    return {
        "spoof": k_sp,
        "kind": sp.kind,
        "drone": drone,
        "start_s": sp.start_s,
        "judged_steps": int(seen.sum()),
        "flagged_steps": int(flagged.sum()),
        "flagged_fraction": round(float(flagged.sum() / seen.sum()), 4) if seen.any() else None,
        "flagged_at_least_once": first is not None,
        "time_to_first_detection_s": after(first),
        "time_to_sustained_detection_s": after(sustained),
        # None where there is no first detection, or no reported fix then (a drone with no GNSS)
        "reported_error_at_first_detection_m": None if first is None else _stat(errors["gnss"][first, i]),
        "worst_error_m": _max(errors["swarmraft"][steps, i]),
        "mean_error_m": _stat(errors["swarmraft"][steps, i]),
        "mean_snapshot_bound_m": _stat(errors["snapshot_bound"][steps, i]),
        "p95_error_to_snapshot_bound": round(float(np.percentile(ratio, 95)), 3) if ratio.size else None,
        "mean_error_after_detection_m": _stat(err[since]),
        "mean_snapshot_bound_after_detection_m": _stat(bound[since]),
    }


def _majority_warnings(log: MissionLog) -> list[str]:
    """A warning when, at some step, more of the alive drones are spoofed than (a-1)//2."""
    sc = log.scenario
    n = sc.drones
    out = []
    if log.spoofed.sum(axis=1).max(initial=0) > (n - 1) // 2:
        out.append(
            f"up to {int(log.spoofed.sum(axis=1).max())} of {n} drones spoofed at once, more "
            f"than (n-1)//2 = {(n - 1) // 2}: the honest drones are no majority and no detector "
            "can be expected to tell them apart"
        )
    up = log.alive & log.in_swarm()
    alive = up.sum(axis=1)
    over = (log.spoofed & up).sum(axis=1) > (alive - 1) // 2
    over &= alive > 0
    if over.any() and not out:
        k = int(np.flatnonzero(over)[0])
        out.append(
            f"from t = {log.t[k]:.1f} s, {int((log.spoofed[k] & up[k]).sum())} of the "
            f"{int(alive[k])} drones alive are spoofed, more than (a-1)//2 = {(int(alive[k]) - 1) // 2}"
        )
    return out


#: A skipped step at most this long after an event of the mission (a fault, or what it set
#: off: a promotion, a removal) is put down to it: a new leader comes within two election
#: timeouts (0.6 s), a committee change or a restarted drone's catch-up takes longer. In a
#: networked run so is the step just before the event (`MissionLog.in_flight_s`), whose
#: record was on its way when it came: a leader SIGKILLed at 20 s took step 199 (19.9 s) with it.
FAULT_SKIP_WINDOW_S = 2.0


def skipped_causes(log: MissionLog) -> dict[str, Any]:
    """Each skipped step put down to one cause: no record at all (a mission that committed
    nothing), before the first committed record (the first election), from
    ``log.in_flight_s`` before an event of the mission (0 in the simulator) to
    FAULT_SKIP_WINDOW_S after it, or neither: unexplained (the first 20 listed by time)."""
    skipped = ~log.committed
    done = np.flatnonzero(log.committed)
    if not done.size:  # nothing committed: no first record to wait for, nothing to put down
        return {
            "no_record": int(skipped.sum()),
            "before_first_record": 0,
            "after_fault": 0,
            "unexplained": 0,
            "unexplained_times_s": [],
        }
    before = skipped & (np.arange(len(log.t)) < done[0])
    near = np.zeros(len(log.t), dtype=bool)
    for t, _ in log.events:
        near |= (log.t >= t - log.in_flight_s - 1e-9) & (log.t <= t + FAULT_SKIP_WINDOW_S + 1e-9)
    after = skipped & ~before & near
    other = skipped & ~before & ~after
    return {
        "no_record": 0,
        "before_first_record": int(before.sum()),
        "after_fault": int(after.sum()),
        "unexplained": int(other.sum()),
        "unexplained_times_s": [round(float(t), 1) for t in log.t[other][:20]],
    }


def honest_cells(log: MissionLog, errors: dict[str, np.ndarray]) -> np.ndarray:
    """(S, n): the (step, drone) cells over which the honest drones' SwarmRaft error is
    compared with their raw GNSS error: a drone never spoofed, alive and in the swarm, at a
    committed step, with both errors (a committed position and a fix). Both means of a
    comparison are taken over these cells, never each over its own."""
    honest = ~log.spoofed.any(axis=0)
    up = log.alive & log.in_swarm() & log.committed[:, None] & honest[None, :]
    return up & np.isfinite(errors["swarmraft"]) & np.isfinite(errors["gnss"])


def _after_faults(
    log: MissionLog, errors: dict[str, np.ndarray], wrong: np.ndarray, cells: np.ndarray
) -> list[dict[str, Any]]:
    """Per fault event, from it to the next one (or the mission's end): the honest drones'
    SwarmRaft error against their raw GNSS over ``cells`` (`honest_cells`), skipped and
    wrong-partition steps."""
    S = len(log.t)
    times = [t for t, _ in log.events] + [float(log.t[-1]) + log.scenario.dt_s]
    out = []
    for (t0, what), t1 in zip(log.events, times[1:], strict=True):
        k0, k1 = _step_of(log.scenario, t0, S), _step_of(log.scenario, t1, S)
        rows = slice(k0, k1)
        out.append(
            {
                "event": what,
                "from_s": round(t0, 3),
                "to_s": round(min(t1, float(log.t[-1])), 3),
                "honest_error_swarmraft_m": _stat(errors["swarmraft"][rows][cells[rows]]),
                "honest_error_gnss_m": _stat(errors["gnss"][rows][cells[rows]]),
                "skipped_steps": int((~log.committed[rows]).sum()),
                "wrong_partition_steps": int(wrong[rows].sum()),
            }
        )
    return out


def honest_excess(log: MissionLog, errors: dict[str, np.ndarray]) -> dict[str, Any]:
    """The steps in which SwarmRaft leaves the honest drones worse off than raw GNSS: their
    mean committed error above their mean raw GNSS error, over the same drones
    (`honest_cells`). The target: never for more than 1 s running."""
    cells = honest_cells(log, errors)
    sw = np.where(cells, errors["swarmraft"], np.nan)
    gn = np.where(cells, errors["gnss"], np.nan)
    have = cells.any(axis=1)
    worse = np.zeros(len(log.t), bool)
    worse[have] = np.nanmean(sw[have], axis=1) > np.nanmean(gn[have], axis=1)
    return {
        "steps": int(worse.sum()),
        "longest_s": round(_runs(worse) * log.scenario.dt_s, 3),
        "time_ranges_s": time_ranges(log.t, worse),
    }


def summarize(log: MissionLog, errors: dict[str, np.ndarray]) -> dict[str, Any]:
    sc = log.scenario
    n, S = sc.drones, len(log.t)
    spoof_ever = log.spoofed.any(axis=0)
    honest = ~spoof_ever
    committed = int(log.committed.sum())
    per_step_min = 2 * (n - 1)
    # the spoofs that began within the log (a launch stopped early is cut before the later ones:
    # they were not missed, they never came)
    end = float(log.t[-1]) if len(log.t) else -np.inf
    detections = [
        _spoof_detection(log, errors, k, d)
        for k, sp in enumerate(sc.spoof)
        if sp.start_s <= end + 1e-9
        for d in sp.drones
    ]
    wrong = wrong_partition(log)
    seen = judged(log)
    cells = honest_cells(log, errors)
    wrong_steps = [
        {
            "step": int(k),
            "t": round(float(log.t[k]), 3),
            "status": str(log.status[k]),
            "honest_flagged": [int(i) + 1 for i in np.flatnonzero(seen[k] & log.faulty[k] & ~log.spoofed[k])],
            "spoofed_not_flagged": [
                int(i) + 1 for i in np.flatnonzero(seen[k] & ~log.faulty[k] & log.spoofed[k])
            ],
        }
        for k in np.flatnonzero(wrong)
    ]
    outages = []
    for o in sc.outage:
        k0 = _step_of(sc, o.start_s, S)
        k1 = S if o.end_s is None else _step_of(sc, o.end_s, S)
        for d in o.drones:
            i = d - 1
            outages.append(
                {
                    "drone": d,
                    "from_s": o.start_s,
                    "to_s": o.end_s,
                    "mean_error_swarmraft_m": _stat(errors["swarmraft"][k0:k1, i]),
                    "mean_error_ins_aligned_m": _stat(errors["ins_aligned"][k0:k1, i]),
                    "mean_error_ins_alone_m": _stat(errors["ins_alone"][k0:k1, i]),
                    "ins_alone_error_at_start_m": _stat(errors["ins_alone"][k0 : k0 + 1, i]),
                    "mean_snapshot_bound_m": _stat(errors["snapshot_bound"][k0:k1, i]),
                }
            )
    hon_mask = honest[None, :] & seen
    # None (not judged) where no honest drone was judged: not 0, which read as "none flagged"
    fp = round(float(log.faulty[hon_mask].mean()), 5) if hon_mask.any() else None
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
        "warnings": _majority_warnings(log),
        "committed_steps": committed,
        "skipped_steps": S - committed,
        "longest_skipped_run": _runs(~log.committed),
        "skipped_causes": skipped_causes(log),
        # None where no step's record was applied by two drones: nothing was compared
        "records_identical_on_all_nodes": log.agreement.identical if log.agreement.checked else None,
        "records_compared": log.agreement.checked,
        "bound_note": BOUND_NOTE,
        "sustained_detection_s": SUSTAIN_S,
        # over the same cells (`honest_cells`): committed steps, drones with both errors
        "honest_error_gnss_m": _stat(errors["gnss"][cells]),
        "honest_error_swarmraft_m": _stat(errors["swarmraft"][cells]),
        "honest_cells_compared": int(cells.sum()),
        "honest_snapshot_bound_m": _stat(errors["snapshot_bound"][:, honest]),
        "honest_false_positive_rate": fp,
        "honest_worse_than_gnss": honest_excess(log, errors),
        "wrong_partition_step_count": len(wrong_steps),
        "wrong_partition_time_ranges_s": time_ranges(log.t, wrong),
        "wrong_partition_steps": wrong_steps,
        "detections": detections,
        "after_faults": _after_faults(log, errors, wrong, cells),
        "outages": outages,
        # None (JSON null) where no step committed: no latency to take a median of
        "latency_ms_median": _stat(log.latency_ms, np.median, 2),
        "latency_ms_p99": _stat(log.latency_ms, lambda v: np.percentile(v, 99), 2),
        "raft_messages_per_committed_step": None if not committed else round(raft_per, 2),
        "raft_minimum_per_step": per_step_min,
        "reports_per_step": round(float(log.report_messages.mean()), 2),
        "refused_proposals": log.refused_proposals,
        "events": [f"{t:.1f} s: {e}" for t, e in log.events],
        "idle_faults": [f"{t:.1f} s: {e}" for t, e in log.idle_faults],
        "integrity": integrity_summary(log),
        # only with a lying-leader fault: the files of other missions stay as they were
        **({"audit": _rounded(log.audit)} if any(f.kind == "lying-leader" for f in sc.fault) else {}),
    }


def _rounded(audit: dict) -> dict:
    return {k: round(v, 3) if isinstance(v, float) else v for k, v in audit.items()}


def misleading_judged(log: MissionLog) -> np.ndarray:
    """(S, n): where misleading information can be judged: a drone in the swarm, in a
    committed record with status ok that gives it both protection levels."""
    ok = (log.status == "ok")[:, None] & log.committed[:, None] & log.in_swarm()
    return ok & ~np.isnan(log.hpl) & ~np.isnan(log.vpl)


def misleading_information(log: MissionLog) -> np.ndarray:
    """(S, n): a committed record with status ok whose position of the drone is further from
    the truth than its protection level (horizontally or vertically)."""
    e = log.verified - log.truth
    with np.errstate(invalid="ignore"):
        over = (np.hypot(e[..., 0], e[..., 1]) > log.hpl) | (np.abs(e[..., 2]) > log.vpl)
    return over & misleading_judged(log)


def integrity_summary(log: MissionLog) -> dict[str, Any]:
    """Protection levels over the committed steps: how often the records were ok, the median
    levels, and the misleading information (error above the level in an ok record)."""
    mis = misleading_information(log)
    ok = log.committed & (log.status == "ok")
    finite = np.isfinite(log.hpl) & ok[:, None]
    # no ok record with a protection level (`paper` gives none): misleading information is
    # not judged, None, not 0; a drone an ok record gives no level is counted apart
    judged = misleading_judged(log)
    unlevelled = ok[:, None] & log.in_swarm() & ~judged
    return {
        "ok_steps": int(ok.sum()),
        "status_counts": {s: int((log.status == s).sum()) for s in sorted(set(log.status.tolist()))},
        "median_hpl_m": round(float(np.median(log.hpl[finite])), 3) if finite.any() else None,
        "median_vpl_m": round(float(np.median(log.vpl[finite])), 3) if finite.any() else None,
        "misleading_drone_steps": int(mis.sum()) if judged.any() else None,
        "ok_drone_steps_without_level": int(unlevelled.sum()),
        "misleading_times_s": [round(float(t), 1) for t in log.t[mis.any(axis=1)][:20]],
    }


def step_rows(log: MissionLog, errors: dict[str, np.ndarray]) -> Iterator[dict[str, Any]]:
    """steps.csv's rows (one per step and drone), one at a time: as a list they held about
    1.5 KB of Python objects a row (54 MB for 64 drones over 60 s)."""
    # nan where not judged (no ok record, or no level in it), as trials.csv has it
    misleading = np.where(misleading_judged(log), misleading_information(log), np.nan)
    wrong = wrong_partition(log)
    member = log.member
    for k in range(len(log.t)):
        for i in range(log.scenario.drones):
            tr, rp, vf = log.truth[k, i], log.reported[k, i], log.verified[k, i]
            yield (
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
                    "wrong_partition": wrong[k],
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
                    "error_ins_aligned": errors["ins_aligned"][k, i],
                    "error_swarmraft": errors["swarmraft"][k, i],
                    "snapshot_bound": errors["snapshot_bound"][k, i],
                    "hpl": log.hpl[k, i],
                    "vpl": log.vpl[k, i],
                    "misleading": misleading[k, i],
                    "leader": log.leader[k],
                    "term": log.term[k],
                    "latency_ms": log.latency_ms[k],
                    "raft_messages": log.raft_messages[k],
                    "report_messages": log.report_messages[k],
                    "status": log.status[k],
                    **({MEMBER_COLUMN: member[k, i]} if member is not None else {}),
                }
            )


def run_and_write(sc: Scenario, out: Path, progress: Any = None, on_step: Any = None) -> MissionResult:
    """Run a mission and write steps.csv, summary.json and scenario.json into ``out``;
    ``on_step(log, k)`` is the simulator's per-step hook (`sim.mission.run_mission`)."""
    return write_results(run_mission(sc, progress, on_step), out)


def write_results(
    log: MissionLog,
    out: Path,
    extra: dict[str, Any] | None = None,
    errors: dict[str, np.ndarray] | None = None,
) -> MissionResult:
    """A mission log's steps.csv, summary.json (with ``extra`` fields added) and scenario.json
    in ``out``: a simulated mission's, or a networked run's (``swarmraft launch``).
    ``errors``: the log's `error_series`, if the caller has it already (computed here if not;
    at 256 drones it is a minute of a 60 s mission's bounds)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    errors = error_series(log) if errors is None else errors
    summary = {**summarize(log, errors), **(extra or {})}
    # strict JSON: a value that does not exist is null, never NaN (which parsers refuse); both
    # texts made before any file is written, so a summary that cannot be written leaves the
    # folder as it was, and each file is swapped in whole
    texts = {
        "summary.json": json.dumps(summary, indent=2, allow_nan=False) + "\n",
        "scenario.json": json.dumps(log.scenario.model_dump(mode="json"), indent=2) + "\n",
    }
    from swarmraft.experiments.results_folder import forget_derived  # (it reads mission folders)

    forget_derived(out)  # the last run's figures, report and recording described other data
    write_rows(out / "steps.csv", step_columns(log), step_rows(log, errors))
    for name, text in texts.items():
        write_text(out / name, text)
    return MissionResult(log, errors, summary)

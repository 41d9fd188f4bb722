"""A scenario's world as its drones sense it, drawn from the scenario's seed: trajectories, GNSS
errors and attacks, INS drift, UWB ranges, and the protocol settings calibrated on that world.

`ScenarioWorld.build(sc)` makes every random draw the simulator's mission makes, in the same
order, so the simulator (`sim.mission`) and each process of a networked swarm (`net.node`)
compute the same world from the same scenario. Everything here is a pure function of the
step k, except the INS estimate, which also depends on where the drone was last aligned
(the host keeps that). No clock, no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from swarmraft.estimation import SnapshotBatch
from swarmraft.estimation.calibration import calibrate
from swarmraft.protocol import ProtocolConfig
from swarmraft.protocol.drift import DriftModel
from swarmraft.protocol.memo import BoundedMemo
from swarmraft.sim.scenario import Scenario
from swarmraft.world import GaussMarkov, UWBRanging
from swarmraft.world.attacks import enlarge
from swarmraft.world.ins import G, InsDrift, InsGrade, ins_grade, ins_sigma
from swarmraft.world.motion import Trajectory, formation_flight, static_swarm
from swarmraft.world.timeline import AttackTimeline, Outage, Spoof

#: at most this many (step, drone) innovations `ScenarioWorld.innovation` remembers (the
#: newest; about 40 MB): a window's innovation is asked for again for M - 1 more windows of W
#: steps, by n drones, so the memo holds n (M + 1) W of them where that is fewer
INNOVATIONS_KEPT = 1 << 17


@dataclass
class ScenarioWorld:
    """Step k's world for S = steps + 1 steps and n drones (indexes 0..n-1)."""

    sc: Scenario
    traj: Trajectory
    gnss_err: np.ndarray  # (S, n, 3) Gauss-Markov receiver error
    grade: InsGrade
    drift: InsDrift
    timeline: AttackTimeline
    uwb: UWBRanging
    fix: np.ndarray  # (S, n, 3) receiver output (spoofed where spoofed), whether or not it has a fix
    has_fix: np.ndarray  # (S, n) bool: False in an outage
    spoofed: np.ndarray  # (S, n) bool
    ranges: np.ndarray  # (S, n, n) measured ranges before any tampering; row i: drone i's
    window_steps: int  # the innovation window in steps
    innovation_sigma: tuple[float, float]  # (horizontal, vertical) of an honest innovation, m
    calibration: dict[str, float]  # the paper detector's tau and epsilon, when calibrated here
    protocol: ProtocolConfig
    rng_keys: np.random.Generator  # the simulator's report keys are drawn from it
    _innovations: BoundedMemo = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        reuse = self.sc.drones * (self.sc.protocol.drift_windows + 1) * self.window_steps
        self._innovations = BoundedMemo(max(1, min(reuse, INNOVATIONS_KEPT)))

    @classmethod
    def build(cls, sc: Scenario) -> ScenarioWorld:
        n, S = sc.drones, sc.steps + 1
        seeds = np.random.SeedSequence(sc.seed).spawn(6)
        rng_motion, rng_gnss, rng_ins, rng_att, rng_keys, rng_range = (
            np.random.default_rng(s) for s in seeds
        )
        if sc.motion.kind == "formation":
            wp = None if sc.motion.waypoints is None else np.array(sc.motion.waypoints, float)
            traj = formation_flight(
                rng_motion, n, sc.duration_s, sc.dt_s, sc.motion.spacing, sc.motion.speed, wp
            )
        else:
            traj = static_swarm(rng_motion, n, sc.duration_s, sc.dt_s, sc.motion.area_size)
        gnss_err = GaussMarkov(sc.gnss.sigma_h, sc.gnss.sigma_v, sc.gnss.tau_s, sc.dt_s).sequence(
            rng_gnss, S, n
        )
        grade = ins_grade(sc.ins.grade)
        drift = InsDrift.draw(rng_ins, n, grade)
        spoofs = [
            Spoof(
                s.kind,
                tuple(d - 1 for d in s.drones),
                s.start_s,
                s.end_s,
                s.magnitude,
                s.rate,
                tuple(p - 1 for p in s.pivots),
                s.angle_deg,
                s.tamper_ranges,
                s.enlarge,
                s.same_direction,
            )
            for s in sc.spoof
        ]
        outages = [Outage(tuple(d - 1 for d in o.drones), o.start_s, o.end_s) for o in sc.outage]
        timeline = AttackTimeline.build(rng_att, spoofs, outages)
        uwb = UWBRanging(
            sc.ranging.sigma, sc.ranging.max_range, sc.ranging.nlos_prob, nlos_mode=sc.ranging.nlos_mode
        )
        # In step order, as the simulator draws them (an area spoof fixes its point at its first step).
        fix, has_fix, spoofed = np.empty((S, n, 3)), np.empty((S, n), bool), np.empty((S, n), bool)
        honest = traj.positions[:S] + gnss_err[:S]
        for k in range(S):
            fix[k], has_fix[k], spoofed[k] = timeline.gnss(traj.t[k], traj.positions[k], honest[k])
        ranges = uwb.measure_steps(rng_range, traj.positions[:S])  # its own generator
        window = sc.protocol.innovation_window_s
        # An honest innovation over the window: the Gauss-Markov GNSS error's change plus the
        # INS drift of a fresh integration over the window, per axis (horizontal, vertical).
        gm = np.sqrt(2 * (1 - np.exp(-window / sc.gnss.tau_s)))
        drift_axis = ins_sigma(grade, window) / np.sqrt(3)
        innovation_sigma = (
            float(np.hypot(gm * sc.gnss.sigma_h, drift_axis)),
            float(np.hypot(gm * sc.gnss.sigma_v, drift_axis)),
        )
        drift_model = None
        # the drag-off test is a temporal test like the gate: off with it (the paper's cases)
        if sc.protocol.drift_windows and sc.protocol.innovation_gate:
            a, g = 0.5 * grade.accel_bias * window**2, grade.gyro_bias * G * window**3 / 6
            drift_model = DriftModel(
                window,
                sc.protocol.drift_windows,
                (sc.gnss.sigma_h, sc.gnss.sigma_v),
                sc.gnss.tau_s,
                (float(np.hypot(a, g)), float(a)),
                sc.protocol.drift_false_alarm,
                sc.protocol.drift_suspect,
            )
        params = dict(sc.protocol.detector_params)
        calibration: dict[str, float] = {}
        if sc.protocol.detector == "paper" and not {"tau", "epsilon"} & set(params):
            noisy = sc.gnss.sigma_h > 0 or sc.gnss.sigma_v > 0 or sc.ranging.sigma > 0
            if noisy:  # the paper's thresholds from honest snapshots of this world (III.E)
                calibration = _calibrate(sc, traj, uwb, np.random.default_rng(seeds[0].spawn(1)[0]))
                params.update(tau=calibration["tau"], epsilon=calibration["epsilon"])
        pcfg = ProtocolConfig(
            n=n,
            detector=sc.protocol.detector,
            detector_params=params,
            gnss_sigma=(sc.gnss.sigma_h, sc.gnss.sigma_v),
            range_sigma=sc.ranging.sigma,
            innovation_gate=sc.protocol.innovation_gate or None,
            innovation_sigma=innovation_sigma,
            drift=drift_model,
        )
        return cls(
            sc,
            traj,
            gnss_err,
            grade,
            drift,
            timeline,
            uwb,
            fix,
            has_fix,
            spoofed,
            ranges,
            max(1, int(round(window / sc.dt_s))),
            innovation_sigma,
            calibration,
            pcfg,
            rng_keys,
        )

    def gnss_output(self, k: int) -> np.ndarray:
        """(n, 3) receiver output at step k (or (K, n, 3) at steps k, a slice), nan in an outage."""
        return np.where(self.has_fix[k][..., None], self.fix[k], np.nan)

    def ins_estimate(self, k: int, base_t: np.ndarray, base_pos: np.ndarray) -> np.ndarray:
        """(n, 3) each drone's INS estimate at step k: aligned to ``base_pos`` (n, 3) at times
        ``base_t`` (n,) s, then dead reckoning (the true motion plus its drift)."""
        t = self.traj.t[k]
        kb = np.minimum(np.round(base_t / self.sc.dt_s).astype(int), len(self.traj.t) - 1)
        moved = self.traj.positions[k] - self.traj.positions[kb, np.arange(self.sc.drones)]
        return base_pos + moved + self.drift.error(t - base_t)

    def measured_ranges(self, k: int, ins: np.ndarray) -> np.ndarray:
        """(n, n) step k's ranges, row i measured by drone i, lengthened where a spoof enlarges
        distances; a drone that tampers with its ranges reports the distances its fake
        position (its fix, or ``ins`` (n, 3) without a fix) implies."""
        ranges = self.ranges[k].copy()
        delay = self.timeline.enlargement(self.traj.t[k], self.sc.drones)
        if delay.any():  # delayed replies: every range of an enlarging drone reads long
            ranges = enlarge(ranges[None], delay[None])[0]
        tamper = self.timeline.tampering(self.traj.t[k])
        if tamper.size:
            shown = np.where(self.has_fix[k][:, None], self.fix[k], ins)
            fake = np.linalg.norm(shown[:, None] - shown[None], axis=2)
            ranges[tamper] = np.where(np.isnan(ranges[tamper]), np.nan, fake[tamper])
        return ranges

    def innovation(self, k: int, i: int) -> np.ndarray | None:
        """GNSS-minus-INS innovation of drone i over the window: how far its GNSS fix moved in
        the last window minus how far its INS says it moved (true motion plus the drift of
        integrating over the window). None without both fixes. Read-only, and remembered for
        the newest INNOVATIONS_KEPT (k, i): a report carries the windows ending at k, k - W,
        ..., so each is asked for again W steps later, and by every resent report (97,434
        calls for 10,200 windows in a 17-drone, 60 s mission)."""
        key = (k, i)
        if key not in self._innovations:
            self._innovations[key] = self._innovation(k, i)
        return self._innovations[key]

    def _innovation(self, k: int, i: int) -> np.ndarray | None:
        base = k - self.window_steps
        if base < 0 or not (self.has_fix[k, i] and self.has_fix[base, i]):
            return None
        now, then = self.fix[k, i], self.fix[base, i]
        if not (np.isfinite(now).all() and np.isfinite(then).all()):
            return None
        w = self.traj.t[k] - self.traj.t[base]
        own = InsDrift(self.drift.accel[i : i + 1], self.drift.gyro[i : i + 1])
        ins_moved = self.traj.positions[k, i] - self.traj.positions[base, i] + own.error(np.full(1, w))[0]
        out = (now - then) - ins_moved
        out.flags.writeable = False
        return out

    def innovations(self, k: int, i: int) -> np.ndarray | None:
        """(M, 3) drone i's innovations over its last M windows (the drag-off test's input,
        `protocol.drift`), newest first: the window ending at step k, then at k - W, ...; a nan
        row where it has none. None when the test is off (M = 0)."""
        m = self.sc.protocol.drift_windows
        if m == 0:
            return None
        rows = [self.innovation(k - j * self.window_steps, i) for j in range(m)]
        return np.array([np.full(3, np.nan) if r is None else r for r in rows])


#: Snapshots the start-up calibration draws: 400, fewer beyond 64 drones so that the drone
#: residuals it collects stay at 400 x 64 (each snapshot gives n multilaterations from n - 1
#: anchors: at 256 drones 400 snapshots took 98 s of a 1 s mission's 106 s, on a loaded machine).
CALIBRATION_SNAPSHOTS, CALIBRATION_RESIDUALS = 400, 400 * 64


def _calibrate(sc: Scenario, traj: Trajectory, uwb: UWBRanging, rng: np.random.Generator):
    """The paper's tau and epsilon calibrated on honest snapshots drawn from the mission's own
    geometry and noise (GNSS white with the scenario's sigmas, UWB ranges)."""
    samples = min(CALIBRATION_SNAPSHOTS, -(-CALIBRATION_RESIDUALS // sc.drones))
    ks = rng.integers(0, len(traj.t), samples)
    truth = traj.positions[ks]
    sig = np.array([sc.gnss.sigma_h, sc.gnss.sigma_h, sc.gnss.sigma_v])
    reported = truth + rng.standard_normal(truth.shape) * sig
    ranges = uwb.measure(rng, truth)
    cal = calibrate(SnapshotBatch(reported, ranges))
    return {"tau": cal.tau, "epsilon": cal.epsilon}

"""A live drone's sensors: its GNSS fix from MAVLink ``GPS_RAW_INT`` (pymavlink, the
``mavlink`` extra) converted into the swarm's local ENU frame, and its UWB ranges from a small
UDP line format (UWB ranges have no standard MAVLink message). docs/records.md describes both.

Each input is read in a thread of its own (pymavlink's ``recv_match`` with a short timeout, a
socket with a timeout), which only stores the latest value with its arrival time; `reading`
takes what is there, under a lock, and never waits, so the asyncio loop is never blocked.

The geodetic conversion is exact (WGS84 geodetic to ECEF to ENU at the swarm's origin, in
float64: well under a millimetre at any distance a swarm flies); the coordinates themselves are
quantised by ``GPS_RAW_INT`` to 1e-7 degree (about 1.1 cm) and 1 mm of altitude.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from swarmraft.net.sources import Reading, SourceError
from swarmraft.net.swarmfile import GeodeticOrigin, MavlinkSourceConfig

_logger = logging.getLogger(__name__)

WGS84_A = 6378137.0  # m, semi-major axis
WGS84_F = 1 / 298.257223563
WGS84_E2 = WGS84_F * (2 - WGS84_F)
#: GPS_RAW_INT fix_type from which the fix is used: 3 = 3D fix (and better: DGPS, RTK)
MIN_FIX_TYPE = 3
POLL_S = 0.2  # how long a reader thread waits for input before it looks at the stop flag


def geodetic_to_ecef(lat_deg: np.ndarray, lon_deg: np.ndarray, alt_m: np.ndarray) -> np.ndarray:
    """(..., 3) Earth-centred Earth-fixed coordinates, m, of WGS84 latitude, longitude and height."""
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    N = WGS84_A / np.sqrt(1 - WGS84_E2 * np.sin(lat) ** 2)
    return np.stack(
        [
            (N + alt_m) * np.cos(lat) * np.cos(lon),
            (N + alt_m) * np.cos(lat) * np.sin(lon),
            (N * (1 - WGS84_E2) + alt_m) * np.sin(lat),
        ],
        axis=-1,
    )


def geodetic_to_enu(lat_deg: float, lon_deg: float, alt_m: float, origin: GeodeticOrigin) -> np.ndarray:
    """(3,) east, north, up in metres of a point from ``origin`` (exact, no flat-earth
    approximation)."""
    lat0, lon0 = np.radians(origin.lat_deg), np.radians(origin.lon_deg)
    d = geodetic_to_ecef(np.float64(lat_deg), np.float64(lon_deg), np.float64(alt_m)) - geodetic_to_ecef(
        np.float64(origin.lat_deg), np.float64(origin.lon_deg), np.float64(origin.alt_m)
    )
    sl, cl, sp, cp = np.sin(lon0), np.cos(lon0), np.sin(lat0), np.cos(lat0)
    R = np.array([[-sl, cl, 0.0], [-sp * cl, -sp * sl, cp], [cp * cl, cp * sl, sp]])
    return R @ d


def parse_range_lines(data: bytes, n: int, own: int) -> tuple[list[tuple[int, float]], list[str]]:
    """The ranges in one datagram of range lines, ``<drone id> <metres>`` each (ASCII, one per
    line, ``#`` starts a comment): ([(index, metres)], [problems, one per bad line])."""
    good, bad = [], []
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError:
        return [], ["not ASCII"]
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        if len(parts) != 2 or not parts[0].isdigit():
            bad.append(f"{line!r} is not '<drone id> <metres>'")
            continue
        j = int(parts[0])
        try:
            r = float(parts[1])
        except ValueError:
            bad.append(f"{line!r}: {parts[1]!r} is not a number")
            continue
        if not 1 <= j <= n or j == own:
            bad.append(f"{line!r}: no other drone {j} (ids 1..{n}, this one is {own})")
        elif not (np.isfinite(r) and r >= 0):
            bad.append(f"{line!r}: a range is a finite number >= 0")
        else:
            good.append((j - 1, r))
    return good, bad


class MavlinkSource:
    """Drone ``drone_id``'s live readings: its latest 3-D fix (``GPS_RAW_INT`` with fix_type
    >= 3) when at most ``max_age_s`` old, else its INS estimate; its latest range to each other
    drone when at most ``max_age_s`` old (else nan). It has no INS input yet: its INS estimate
    is the verified position it was last realigned to (before the first, its last fix), and it
    reports no innovation."""

    def __init__(
        self,
        connection: Any,
        ranges_socket: socket.socket,
        origin: GeodeticOrigin,
        drone_id: int,
        n: int,
        max_age_s: float,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.conn, self.sock, self.origin = connection, ranges_socket, origin
        self.id, self.n, self.max_age_s, self.clock = drone_id, n, max_age_s, clock
        self._lock = threading.Lock()
        self._fix: tuple[float, np.ndarray | None] | None = None  # (arrival, ENU or None: no fix)
        self._ranges = np.full(n, np.nan)
        self._range_t = np.full(n, -np.inf)
        self._ins: np.ndarray | None = None  # the last realignment; before it, the last fix
        self.counters = {"gps_raw_int": 0, "range_lines": 0, "bad_range_lines": 0}
        self._realigned = False
        self._stop = threading.Event()
        self._threads = [
            threading.Thread(target=self._read_mavlink, name=f"drone-{drone_id}-mavlink", daemon=True),
            threading.Thread(target=self._read_ranges, name=f"drone-{drone_id}-ranges", daemon=True),
        ]
        for t in self._threads:
            t.start()

    @classmethod
    def open(
        cls, config: MavlinkSourceConfig, origin: GeodeticOrigin, drone_id: int, n: int
    ) -> MavlinkSource:
        """Opens the MAVLink connection and binds the range socket; SourceError if either fails."""
        try:
            from pymavlink import mavutil
        except ImportError:
            raise SourceError("a mavlink source needs pymavlink: pip install 'swarmraft[mavlink]'") from None
        where = f"drones.{drone_id}.source"
        try:
            conn = mavutil.mavlink_connection(config.connect)
        except Exception as exc:  # pymavlink raises many kinds
            raise SourceError(f"{where}.connect: cannot open {config.connect!r} ({exc})") from None
        host, port = config.ranges_address
        sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind((host, port))
        except OSError as exc:
            sock.close()
            conn.close()
            raise SourceError(
                f"{where}.ranges: cannot bind UDP {host}:{port}: {exc.strerror or exc}"
            ) from None
        sock.settimeout(POLL_S)
        return cls(conn, sock, origin, drone_id, n, config.max_age_s)

    # -- the reader threads: store the latest values ----------------------------------------
    def on_gps_raw_int(self, msg: Any, arrival: float) -> None:
        """A GPS_RAW_INT message (lat, lon in 1e-7 degree, alt in mm, fix_type)."""
        pos = None
        if msg.fix_type >= MIN_FIX_TYPE:
            pos = geodetic_to_enu(msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3, self.origin)
        with self._lock:
            self._fix = (arrival, pos)
            if pos is not None and not self._realigned:
                self._ins = pos
            self.counters["gps_raw_int"] += 1

    def on_range_datagram(self, data: bytes, arrival: float) -> None:
        good, bad = parse_range_lines(data, self.n, self.id)
        with self._lock:
            for j, r in good:
                self._ranges[j], self._range_t[j] = r, arrival
            self.counters["range_lines"] += len(good)
            self.counters["bad_range_lines"] += len(bad)
        if bad:
            _logger.warning("drone %d: %d bad range lines, the first: %s", self.id, len(bad), bad[0])

    def _read_mavlink(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.conn.recv_match(type="GPS_RAW_INT", blocking=True, timeout=POLL_S)
            except OSError:
                if self._stop.is_set():
                    return
                _logger.exception("drone %d: MAVLink read failed", self.id)
                time.sleep(POLL_S)
                continue
            if msg is not None:
                self.on_gps_raw_int(msg, self.clock())

    def _read_ranges(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(65535)
            except TimeoutError:
                continue
            except OSError:
                return  # closed
            self.on_range_datagram(data, self.clock())

    # -- the host's side -------------------------------------------------------------------
    def reading(self, k: int) -> Reading | None:
        now = self.clock()
        with self._lock:
            fresh = now - self._range_t <= self.max_age_s
            ranges = np.where(fresh, self._ranges, np.nan)
            fix = None
            if self._fix is not None and now - self._fix[0] <= self.max_age_s:
                fix = self._fix[1]
            ins = self._ins
        if fix is not None:
            return Reading(fix.copy(), "gnss", ranges, None, fix.copy() if ins is None else ins.copy())
        if ins is None:
            return None
        return Reading(ins.copy(), "ins", ranges, None, ins.copy())

    def realign(self, k: int, position: np.ndarray) -> None:
        with self._lock:
            self._ins = np.asarray(position, float).copy()
            self._realigned = True

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=2 * POLL_S + 1)
        self.sock.close()
        self.conn.close()

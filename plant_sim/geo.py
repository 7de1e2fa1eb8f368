"""Geography of the track: WGS-84 latitude/longitude ↔ the 1-D track position s [m], and distances.

Two distances, for two purposes:

- **On the ellipsoid** (`geodesic_m`, `TrackGeometry`): the truth the plant runs on. Geodesics on the
  WGS-84 ellipsoid by Karney's algorithm (C. F. F. Karney, "Algorithms for geodesics", J. Geodesy 87
  (2013) 43–55), through pyproj's `Geod`, which wraps PROJ's C implementation of it (round-off
  accuracy, ~15 nm; vectorised over numpy arrays).
- **On a sphere** (`haversine_m`): what the anti-collision device of seed 002 §IX computes ("the
  formula of distance between points on a sphere"), with the IUGG mean radius R1 of the WGS-84
  ellipsoid. Its error against the ellipsoid is up to 0.56 % of the distance (north–south at the
  equator, where the meridian's radius of curvature a (1 − e²) is 6 335 km; a few m per km), which is
  part of what a device built that way sees.

Angles are degrees (latitude + north, longitude + east, heading/azimuth clockwise from true north in
[0, 360)); lengths are metres. The plant's track position s is the length along the polyline from its
first point, so the 1-D dynamics and the GPS see the same train.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from pyproj import Geod

from plant_sim.errors import PlantConfigError

# WGS-84 defining constants (NIMA TR8350.2, 3rd ed., table 3.1)
WGS84_A_M = 6_378_137.0                 # semi-major axis a [m]
WGS84_INV_F = 298.257_223_563           # inverse flattening 1/f [-]
WGS84_B_M = WGS84_A_M * (1.0 - 1.0 / WGS84_INV_F)  # semi-minor axis b = a (1 − f) [m]
# IUGG mean radius R1 = (2a + b)/3 (H. Moritz, "Geodetic Reference System 1980", J. Geodesy 74 (2000)
# 128–133): 6 371 008.771 m for WGS-84, usually quoted as 6 371 008.8 m.
MEAN_RADIUS_M = (2.0 * WGS84_A_M + WGS84_B_M) / 3.0

GEOD = Geod(a=WGS84_A_M, rf=WGS84_INV_F)  # Karney (2013) geodesics on WGS-84, via PROJ


def haversine_m(lat1_deg, lon1_deg, lat2_deg, lon2_deg, radius_m: float = MEAN_RADIUS_M):
    """Great-circle distance [m] between (lat1, lon1) and (lat2, lon2) [deg] on a sphere of `radius_m`.

    Haversine formula (R. W. Sinnott, "Virtues of the Haversine", Sky and Telescope 68 (2) 1984, 159):
        a = sin²(Δφ/2) + cos φ1 cos φ2 sin²(Δλ/2),   d = 2 R atan2(√a, √(1 − a)),
    well conditioned for the short distances of a train (unlike the spherical law of cosines).
    Scalars or numpy arrays (broadcast); a float for scalar input.
    """
    phi1, phi2 = np.radians(lat1_deg), np.radians(lat2_deg)
    dphi = phi2 - phi1
    dlmb = np.radians(np.asarray(lon2_deg, dtype=float) - np.asarray(lon1_deg, dtype=float))
    a = np.sin(dphi / 2.0) ** 2 + np.cos(phi1) * np.cos(phi2) * np.sin(dlmb / 2.0) ** 2
    a = np.clip(a, 0.0, 1.0)
    d = 2.0 * radius_m * np.arctan2(np.sqrt(a), np.sqrt(1.0 - a))
    return float(d) if np.ndim(d) == 0 else d


def geodesic_m(lat1_deg, lon1_deg, lat2_deg, lon2_deg):
    """Geodesic distance [m] on the WGS-84 ellipsoid from (lat1, lon1) to (lat2, lon2) [deg], Karney (2013).

    Scalars or numpy arrays of one shape; a float for scalar input.
    """
    _, _, d = GEOD.inv(lon1_deg, lat1_deg, lon2_deg, lat2_deg)
    return float(d) if np.ndim(d) == 0 else np.asarray(d)


def destination(lat_deg, lon_deg, azimuth_deg, distance_m):
    """(lat, lon, heading) [deg] reached from (lat, lon) going `distance_m` [m] along the geodesic that
    starts with `azimuth_deg` (Karney's direct problem on WGS-84). Heading is the geodesic's azimuth at
    the end point, in [0, 360). A negative distance goes backwards. Scalars or arrays."""
    lon2, lat2, back = GEOD.fwd(lon_deg, lat_deg, azimuth_deg, distance_m)
    heading = np.mod(np.asarray(back, dtype=float) + 180.0, 360.0)
    if np.ndim(lat2) == 0:
        return float(lat2), float(lon2), float(heading)
    return np.asarray(lat2), np.asarray(lon2), heading


def offset_north_east(lat_deg, lon_deg, north_m, east_m):
    """(lat, lon) [deg] of the point displaced by (north_m, east_m) [m] from (lat, lon): the geodesic of
    length √(n² + e²) with azimuth atan2(e, n). Used to put a receiver's horizontal error on a position."""
    dist = np.hypot(north_m, east_m)
    az = np.degrees(np.arctan2(east_m, north_m))
    lon2, lat2, _ = GEOD.fwd(lon_deg, lat_deg, az, dist)
    if np.ndim(lat2) == 0:
        return float(lat2), float(lon2)
    return np.asarray(lat2), np.asarray(lon2)


def polyline_from_legs(lat0_deg: float, lon0_deg: float,
                       legs: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    """Points [(lat, lon), ...] of a polyline that starts at (lat0, lon0) and follows `legs`, each
    (azimuth_deg at the leg's start, length_m) along a geodesic. Its length is exactly Σ length_m."""
    pts = [(float(lat0_deg), float(lon0_deg))]
    for k, leg in enumerate(legs):
        try:
            az, length = (float(c) for c in leg)
        except (TypeError, ValueError):
            raise PlantConfigError(f"polyline leg {k}: expected (azimuth_deg, length_m), got {leg!r}") \
                from None
        if not (math.isfinite(az) and math.isfinite(length) and length > 0.0):
            raise PlantConfigError(f"polyline leg {k}: need a finite azimuth and a length > 0 m, got {leg!r}")
        lat, lon, _ = destination(pts[-1][0], pts[-1][1], az, length)
        pts.append((lat, lon))
    return pts


class TrackGeometry:
    """A track as a polyline of WGS-84 points joined by geodesics, and its 1-D position s [m].

    s = 0 at the first point and grows along the polyline; `length_m` is the sum of the geodesic
    lengths of the segments. `at(s)` gives the point and heading at s (beyond the ends it extrapolates
    along the first/last geodesic, so a train that overruns the drawn track still has a position);
    `locate(lat, lon)` projects a point onto the track and gives its s and signed offset.
    """

    def __init__(self, points: Sequence[Sequence[float]], where: str = "track polyline") -> None:
        rows = []
        for k, p in enumerate(points):
            try:
                lat, lon = (float(c) for c in p)
            except (TypeError, ValueError):
                raise PlantConfigError(f"{where} point {k}: expected (lat_deg, lon_deg), got {p!r}") from None
            if not (math.isfinite(lat) and math.isfinite(lon) and -90.0 <= lat <= 90.0
                    and -180.0 <= lon <= 180.0):
                raise PlantConfigError(f"{where} point {k}: need -90 <= lat <= 90 and -180 <= lon <= 180 "
                                       f"degrees, got {p!r}")
            rows.append((lat, lon))
        if len(rows) < 2:
            raise PlantConfigError(f"{where}: need at least 2 points (lat_deg, lon_deg), got {len(rows)}")
        pts = np.array(rows)
        self.lat_deg = pts[:, 0]
        self.lon_deg = pts[:, 1]
        az, _, seg = GEOD.inv(self.lon_deg[:-1], self.lat_deg[:-1], self.lon_deg[1:], self.lat_deg[1:])
        seg = np.asarray(seg, dtype=float)
        short = np.flatnonzero(seg < 1e-3)
        if short.size:
            k = int(short[0])
            raise PlantConfigError(f"{where}: points {k} and {k + 1} coincide ({rows[k]} and {rows[k + 1]}); "
                                   "consecutive points must be at least 1 mm apart")
        self.segment_m = seg                                        # (n−1,) geodesic lengths
        self.azimuth_deg = np.mod(np.asarray(az, dtype=float), 360.0)  # (n−1,) azimuth at segment start
        self.s_knots_m = np.concatenate([[0.0], np.cumsum(seg)])    # (n,) s of each point

    @property
    def length_m(self) -> float:
        """Total length of the polyline [m] (sum of the geodesic segment lengths)."""
        return float(self.s_knots_m[-1])

    def _segment_of(self, s_m: np.ndarray) -> np.ndarray:
        k = np.searchsorted(self.s_knots_m, s_m, side="right") - 1
        return np.clip(k, 0, len(self.segment_m) - 1)

    def at(self, s_m):
        """(lat_deg, lon_deg, heading_deg) at track position s [m]; scalars or arrays of s."""
        s = np.asarray(s_m, dtype=float)
        k = self._segment_of(s)
        return destination(self.lat_deg[k], self.lon_deg[k], self.azimuth_deg[k], s - self.s_knots_m[k])

    def locate(self, lat_deg: float, lon_deg: float,
               s_range_m: tuple[float, float] | None = None) -> tuple[float, float]:
        """(s_m, offset_m) of the point of the track nearest to (lat, lon): s along the track [m] and the
        signed distance from it [m], + to the right of the running direction.

        Each segment is searched for the foot of the perpendicular (the along-track distance from the
        segment start, refined twice by Newton steps on the geodesic, clipped to the segment), and the
        segment with the smallest offset wins; `s_range_m` = (lo, hi) limits the search to the
        segments overlapping it (e.g. around the last known position, where a track passes near itself).
        """
        lat, lon = float(lat_deg), float(lon_deg)
        seg = np.arange(len(self.segment_m))
        if s_range_m is not None:
            lo, hi = s_range_m
            keep = (self.s_knots_m[1:] >= lo) & (self.s_knots_m[:-1] <= hi)
            seg = seg[keep] if keep.any() else seg
        lat0, lon0, az0, length = (self.lat_deg[seg], self.lon_deg[seg], self.azimuth_deg[seg],
                                   self.segment_m[seg])
        plat, plon = np.full(seg.shape, lat), np.full(seg.shape, lon)
        # first guess: the point's distance from the segment start projected on the segment's azimuth
        az_p, _, d_p = GEOD.inv(lon0, lat0, plon, plat)
        along = np.clip(np.asarray(d_p) * np.cos(np.radians(np.asarray(az_p) - az0)), 0.0, length)
        for _ in range(2):  # Newton: move the foot by the projection of (foot → point) on the heading there
            flat, flon, head = destination(lat0, lon0, az0, along)
            az_q, _, d_q = GEOD.inv(flon, flat, plon, plat)
            step = np.asarray(d_q) * np.cos(np.radians(np.asarray(az_q) - head))
            along = np.clip(along + step, 0.0, length)
        flat, flon, head = destination(lat0, lon0, az0, along)
        az_q, _, d_q = GEOD.inv(flon, flat, plon, plat)
        d_q = np.asarray(d_q)
        best = int(np.argmin(d_q))
        side = math.copysign(1.0, math.sin(math.radians(float(np.asarray(az_q)[best] - head[best]))))
        return float(self.s_knots_m[seg[best]] + along[best]), side * float(d_q[best])

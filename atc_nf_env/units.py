"""Units and the physical constants of the paper's setting.

The public API speaks nautical miles (nm), knots (kt) and seconds (s); the paper
gives the wind's standard deviation in m/s, so that one conversion lives here.
"""

from __future__ import annotations

#: Knots per metre per second (1 kt = 1852 m / 3600 s).
KT_PER_MPS: float = 3600.0 / 1852.0

#: Seconds per hour: a speed in kt times seconds / 3600 is a distance in nm.
SECONDS_PER_HOUR: float = 3600.0

#: Airbus A321 at FL330 (paper, section IV-A): airspeed envelope and nominal airspeed, kt.
AIRSPEED_MIN_KT: float = 366.0
AIRSPEED_MAX_KT: float = 540.0
AIRSPEED_NOMINAL_KT: float = 454.0

#: Aircraft disk radius, nm: two disks touch at the 5 nm separation minimum.
AIRCRAFT_RADIUS_NM: float = 2.5
SEPARATION_MIN_NM: float = 2.0 * AIRCRAFT_RADIUS_NM

#: Standard deviation of each wind component (paper, section IV-A), m/s.
WIND_SIGMA_MPS: float = 5.17

#: The MPC's sampling period T (paper, section IV-D), s.
DECISION_PERIOD_S: float = 300.0


def mps_to_kt(speed_mps: float) -> float:
    """Convert a speed from metres per second to knots."""
    return speed_mps * KT_PER_MPS

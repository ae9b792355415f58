"""Physical constants used by the planner, each with its source."""

MU_EARTH_KM3_S2 = 398600.4418  # WGS-84 / EGM96 gravitational parameter
R_EARTH_KM = 6378.137  # WGS-84 equatorial radius
J2 = 1.08262668e-3  # EGM96 / WGS-84 unnormalised zonal coefficient (DESIGN.md section 2)
F_EARTH = 1.0 / 298.257223563  # WGS-84 flattening
OMEGA_EARTH_RAD_S = 7.2921150e-5  # IERS nominal mean angular velocity of the Earth
R_SUN_KM = 696000.0  # IAU 2015 nominal solar radius
DAY_S = 86400.0
MIN_PERIGEE_HEIGHT_KM = 100.0  # below this an orbit decays within hours: refuse it

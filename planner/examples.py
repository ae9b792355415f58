"""The paper's worked example (Hou et al. 2023, Table 1 and section 3.3) as planner objects.

Both epochs 2022-11-27 16:00:00 UTC; heights above ``R_EARTH_KM``; the ground station at
31.1 N, 121.3 E on the ellipsoid, tracking from the horizon. The service's request example
(``app.schemas.PAPER_EXAMPLE``) is the same scene as JSON (tests/planner/test_plan.py holds them equal).
"""

from datetime import UTC, datetime

from planner.elements import Elements
from planner.propagation import Station

PAPER_EPOCH = datetime(2022, 11, 27, 16, 0, tzinfo=UTC)
PAPER_TARGET = Elements(PAPER_EPOCH, 700.0, 600.0, 43.0, 290.0, 100.0, 200.0)
PAPER_OBSERVER = Elements(PAPER_EPOCH, 700.0, 350.0, 99.0, 10.0, 0.0, 316.5)
PAPER_STATION = Station(31.1, 121.3, 0.0, 0.0)

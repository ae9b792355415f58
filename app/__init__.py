"""GSA-ISAR web service: FastAPI over the planner (and, later, the attitude estimator)."""

"""GSA-ISAR web service: FastAPI over the planner and the attitude estimator."""

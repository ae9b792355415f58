from fastapi import APIRouter

from app.api.routes import access, estimates, plans, scenes
from app.schemas import ERROR_RESPONSES

api_router = APIRouter(responses=ERROR_RESPONSES)
api_router.include_router(plans.router)
api_router.include_router(access.router)
api_router.include_router(estimates.router)
api_router.include_router(scenes.router)

from fastapi import APIRouter

from app.api.routes import access, plans

api_router = APIRouter()
api_router.include_router(plans.router)
api_router.include_router(access.router)
